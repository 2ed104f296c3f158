"""`lpv-sysid config`: where the shipped default configuration files are.

    lpv-sysid config                        # every shipped default, one path a line
    lpv-sysid config synthesis.yaml         # the path of one, e.g. to copy and edit it:
    cp "$(lpv-sysid config synthesis.yaml)" my_synthesis.yaml

The defaults the commands use when no ``--config`` is given (``demo``, ``coverage``,
``chain``) are these files, inside the installed package (:mod:`lpv_sysid.configuration.defaults`);
in a source checkout they are also ``config/``.
"""

from __future__ import annotations

import argparse

COMMAND = "config"
HELP = "print the paths of the shipped default config files (all, or the NAMEs given)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help="file names, e.g. synthesis.yaml (default: all)"
    )


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.configuration.defaults import config_file, config_names

    for name in args.names or config_names():
        print(config_file(name))
    return 0
