"""The `mantis` command line."""
import sys


def main(argv=None):
    print('mantis: not yet implemented', file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(main())
