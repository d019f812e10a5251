"""`herd-ros params [NODE]`: a node's parameters from its table (:mod:`herd_ros.params`):
as a Markdown table, as its ``config/<node>.yaml``, or write those files."""
from __future__ import annotations

from pathlib import Path

from herd_ros.errors import HerdInputError

HELP = "show a node's parameters (table or YAML) or write the config/*.yaml files"


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    from herd_ros.params import NODES
    parser.add_argument('node', metavar='NODE', nargs='?', choices=NODES,
                        help=f'one of {", ".join(NODES)}; none = all')
    parser.add_argument('--yaml', action='store_true',
                        help='print the config file (with every parameter and its default) '
                             'instead of the table')
    parser.add_argument('--write', metavar='DIR', nargs='?', const='config',
                        help='write each config/<node>.yaml (and flocking.yaml, '
                             'herding.yaml) under DIR')


def _tables(node):
    from herd_ros.params import NODES, table
    from herd_ros.params.controller import FLOCKING_TABLE, HERDING_TABLE
    tables = [table(n) for n in ([node] if node else NODES)]
    if node in (None, 'controller'):
        tables += [FLOCKING_TABLE, HERDING_TABLE]
    return tables


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.params import markdown_table, render_yaml
    tables = _tables(args.node)
    if args.write:
        out = Path(args.write)
        if not out.is_dir():
            raise HerdInputError(f'--write: {out} is not a directory')
        for t in tables:
            (out / t.config_file).write_text(render_yaml(t))
            print(f'wrote {out / t.config_file}')
        return 0
    for t in tables:
        if args.yaml:
            print(render_yaml(t), end='')
        elif t.file == '':
            print(f'## {t.node}\n\n{markdown_table(t)}')
    return 0
