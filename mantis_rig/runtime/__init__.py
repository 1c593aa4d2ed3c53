"""What every node process runs on: its executors and spinning (`executors`), Ctrl-C and
SIGTERM (`stopping`), DDS kept on this machine (`ros_env`), a flat memory (`memory`), nodes
without default QoS-event handlers (`lean_node`) and a clock-driven callback thread
(`clock_ticker`). Below the nodes: it imports none of them."""
