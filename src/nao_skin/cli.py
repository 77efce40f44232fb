"""Command line entry point: ``nao-skin <subcommand> ...``.

Subcommands are registered in :func:`build_parser`; each one sets
``func`` (callable taking the parsed args, returning an exit code).
"""
import argparse
import sys


def build_parser():
    parser = argparse.ArgumentParser(
        prog='nao-skin', description='nao_skin tools')
    parser.add_subparsers(dest='command', metavar='COMMAND')
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, 'func', None)
    if func is None:
        parser.print_help()
        return 0 if args.command is None else 2
    return int(func(args) or 0)


if __name__ == '__main__':
    sys.exit(main())
