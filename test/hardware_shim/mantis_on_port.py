"""`mantis ARGS...` with stage_node's serial_port set to PORT (the KDC101 emulator's):
``python mantis_on_port.py PORT bringup --backend hardware ...`` (test/hardware_rig.py)."""
import sys

from mantis_rig.cli import trial_commands as cli_trial
from mantis_rig.cli.main import main as mantis_main


def main() -> int:
    port, argv = sys.argv[1], sys.argv[2:]
    stack_config = cli_trial.stack_config

    def on_port(args):
        config = stack_config(args)
        config.devices.setdefault('stage_node', {})['serial_port'] = port
        return config
    cli_trial.stack_config = on_port
    return mantis_main(argv)


if __name__ == '__main__':
    sys.exit(main())
