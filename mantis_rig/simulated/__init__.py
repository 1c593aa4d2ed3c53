"""The simulated rig, in one wing: the simulated devices behind the real ones' interfaces
(`sim_stage`, `sim_force`, `sim_camera`), how they reach the simulated world (`world_port`,
`local_world`: the world's runner in this process), the world's node and its clock
(`sim_world_node`, `shared_clock`), and `sim_rig`, the simulated rig's own process.

Its modules sit at the layer of their role (docs/architecture.md): the devices with the real
drivers, the world's node with the nodes, `sim_rig` with the stack."""
