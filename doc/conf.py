"""Sphinx configuration of herd_ros's documentation (rosdoc2-compatible layout: ``doc/``
with ``conf.py`` and ``index.md``).

Build: ``.venv/bin/python -m sphinx -W -b html doc doc/_build/html`` (``make docs``;
``make test`` builds it with warnings as errors, test/test_docs.py). Two pages are
generated here from the code, so they cannot drift from it: ``_generated/parameters.md``
(every node's parameter table, herd_ros.params) and ``_generated/cli.md`` (every
``herd-ros`` verb's ``--help``, from its argparse parser).
"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

project = 'herd_ros'
author = 'herd_ros developers'
extensions = ['myst_parser', 'sphinx.ext.autodoc', 'sphinx.ext.napoleon']
source_suffix = {'.md': 'markdown'}
exclude_patterns = ['_build']
myst_heading_anchors = 3
html_theme = 'alabaster'
html_title = 'herd_ros'
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'
suppress_warnings = ['myst.header']


def _write_if_changed(path: Path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def generate_pages(out: Path = HERE / '_generated'):
    """parameters.md and cli.md from the parameter tables and the argparse parsers."""
    from herd_ros.cli.main import build_parser
    from herd_ros.params import NODES, markdown_table, table
    from herd_ros.params.controller import FLOCKING_TABLE, HERDING_TABLE
    parts = ['# Node parameters', '',
             'Every parameter of every node, rendered from its table '
             '(`herd_ros/params/<node>.py`), which also declares it, checks it and writes '
             '`config/<node>.yaml` (`herd-ros params --write`).', '']
    for t in [table(n) for n in NODES] + [FLOCKING_TABLE, HERDING_TABLE]:
        title = t.node if not t.file else f'{t.node} ({t.file})'
        parts += [f'## {title}', '', f'`config/{t.config_file}`', '', markdown_table(t), '']
    _write_if_changed(out / 'parameters.md', '\n'.join(parts))
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == '_SubParsersAction')
    parts = ['# The command line: `herd-ros`', '',
             'Every verb with its options, as `herd-ros VERB --help` prints them (generated '
             'from the parsers).', '', '```text', parser.format_help().rstrip(), '```', '']
    for verb, p in sub.choices.items():
        p.prog = f'herd-ros {verb}'
        parts += [f'## herd-ros {verb}', '', '```text', p.format_help().rstrip(), '```', '']
    _write_if_changed(out / 'cli.md', '\n'.join(parts))


generate_pages()
