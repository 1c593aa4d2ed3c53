"""Hardware abstraction: one interface per device, a real and a simulated backend each."""
