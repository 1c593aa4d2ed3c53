"""The devices `mantis doctor` checks, built from the rig parameters and none opened here:
the real ones (HardwareRig), or the simulated ones on a world of the params' scene run in this
process (SimulatedDevices: devices only, no nodes, unlike simulated.sim_rig.SimRig)."""
from __future__ import annotations

from .check_report import Options


class HardwareRig:
    """The real devices, built from the parameters by mantis_rig.backends (none opened here)."""

    sim = False

    def __init__(self, options: Options):
        self.options = options
        self.params = options.params

    def make_stage(self, choice):
        """choice: the port choose_stage_port chose (discovery.StageChoice)."""
        from mantis_rig.backends import make_stage
        return make_stage('hardware', choice=choice, counts_per_mm=self.params.counts_per_mm)

    def make_daq(self):
        from mantis_rig.backends import make_force_daq
        return make_force_daq('hardware', config=self.params.daq_config())

    def make_trigger(self):
        from mantis_rig.backends import make_camera_trigger
        return make_camera_trigger('hardware', output=self.params.trigger_output)


class SimulatedDevices:
    """The simulated rig's devices, built by mantis_rig.backends, on a world of the params'
    scene run in this process."""

    sim = True

    def __init__(self, options: Options):
        self.options = options
        self.params = options.params
        self.runner = None

    def __enter__(self):
        from mantis_rig.simulated.local_world import LocalWorldPort, WorldRunner
        from mantis_sim.scene import load_scene
        from mantis_sim.world import World
        self.scene = load_scene(self.params.scene, list(self.params.scene_overrides))
        self.runner = WorldRunner(World(self.scene),
                                  real_time_factor=self.options.real_time_factor).start()
        self.port = LocalWorldPort(self.runner)
        return self

    def __exit__(self, *exc):
        if self.runner is not None:
            self.runner.stop()
        return False

    def rest_force_n(self) -> float:
        """The simulated tendon's true force now (the stage at rest)."""
        return float(self.port.tendon_force(self.port.now_s(), 1.0, 1, 10.0)[0])

    def make_stage(self, choice=None):
        from mantis_rig.backends import make_stage
        return make_stage('sim', self.port)

    def make_daq(self):
        from mantis_rig.backends import make_force_daq
        return make_force_daq('sim', self.port, scene=self.scene, seed=self.params.seed,
                              config=self.params.daq_config())

    def make_trigger(self):
        from mantis_rig.backends import make_camera_trigger
        return make_camera_trigger('sim', self.port, scene=self.scene)


__all__ = ['HardwareRig', 'SimulatedDevices']
