"""`herd-ros`: the offline front door (doc/formats.md, and the command-line page).

Every verb lives in its own module ``herd_ros.cli.<verb>`` exposing

* ``HELP``: one line for ``herd-ros --help``;
* ``add_arguments(parser)``: its options;
* ``run(args) -> int``: the work; returns the exit status.

Bad input raises :class:`herd_ros.errors.HerdInputError`; it is printed as one line
``herd-ros <verb>: error: ...`` with exit status 2, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from herd_ros.errors import HerdInputError, InputNote

class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default only when it has one worth saying: not for None, not for
    flags, and not when the help text already names it."""

    def _get_help_string(self, action):
        text = action.help or ''
        if (action.default is None or action.default is False
                or action.default is argparse.SUPPRESS or 'default' in text.lower()
                or action.required):
            return text
        return super()._get_help_string(action)


# verb name -> module name under herd_ros.cli
VERBS = {
    'fit': 'fit',
    'predict': 'predict',
    'simulate': 'simulate',
    'report': 'report',
    'synth': 'synth',
    'ingest': 'ingest',
    'import': 'import_data',
    'bag-info': 'bag_info',
    'imitate': 'imitate',
    'imitate-sim': 'imitate_sim',
    'flock': 'flock',
    'herding': 'herding',
    'demo': 'demo',
    'herd-file': 'herd_file',
    'params': 'params',
}


def build_parser(verbs=None) -> argparse.ArgumentParser:
    """The parser of ``verbs`` (default: all). ``main`` builds only the verb asked for, so
    a verb pays for its own imports only (``ingest`` does not import the fit machinery)."""
    parser = argparse.ArgumentParser(
        prog='herd-ros',
        description='Learn how a herd moves from GPS data and drive robot fleets with it.',
    )
    sub = parser.add_subparsers(dest='verb', metavar='VERB')
    sub.required = True
    for verb in (VERBS if verbs is None else verbs):
        module_name = VERBS[verb]
        module = importlib.import_module(f'herd_ros.cli.{module_name}')
        p = sub.add_parser(verb, help=module.HELP, description=module.HELP,
                           formatter_class=DefaultsHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run,
                       _keeps_freed_memory=getattr(module, 'KEEPS_FREED_MEMORY', False))
    return parser


def verb_help(module_name: str) -> str:
    """A verb module's ``HELP``, read from its source without importing it (the modules
    import numpy, pandas, scipy and numba at the top: 1.5 s for all fifteen); imported when
    the source cannot be read."""
    import ast
    from importlib.util import find_spec
    name = f'herd_ros.cli.{module_name}'
    try:
        with open(find_spec(name).origin, encoding='utf-8') as fh:
            tree = ast.parse(fh.read())
        for node in tree.body:
            if (isinstance(node, ast.Assign) and len(node.targets) == 1
                    and getattr(node.targets[0], 'id', None) == 'HELP'):
                return str(ast.literal_eval(node.value))
    except (OSError, SyntaxError, ValueError, TypeError, AttributeError):
        pass
    return importlib.import_module(name).HELP


def overview_parser() -> argparse.ArgumentParser:
    """The parser of ``herd-ros`` without a verb (``--help``, a mistyped verb): the verbs
    and their one-line help, no verb module imported."""
    parser = argparse.ArgumentParser(
        prog='herd-ros',
        description='Learn how a herd moves from GPS data and drive robot fleets with it.',
        epilog='herd-ros VERB --help shows the options of a verb.',
    )
    sub = parser.add_subparsers(dest='verb', metavar='VERB')
    sub.required = True
    for verb, module_name in VERBS.items():
        sub.add_parser(verb, help=verb_help(module_name), add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one verb; as the console script (``argv`` None) the process then ends at once
    (:func:`herd_ros.process_exit.exit_process`: no 0.4 s interpreter teardown), and a
    verb whose module sets ``KEEPS_FREED_MEMORY`` keeps the memory it frees
    (:func:`herd_ros.process_memory.keep_freed_memory`)."""
    status = _main(argv)
    if argv is None:
        from herd_ros.process_exit import exit_process
        exit_process(status)
    return status


def _note(verb: str):
    """A ``warnings.showwarning`` that prints an :class:`~herd_ros.errors.InputNote` (ids
    renamed, columns taken by another name) as a note of the verb and any other warning as
    Python would."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, InputNote):
            print(f'herd-ros {verb}: note: {message}', file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)
    return show


def _main(argv: list[str] | None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    if not (words and words[0] in VERBS):
        overview_parser().parse_args(words)         # prints the help or the error, exits
        return 2
    args = build_parser([words[0]]).parse_args(words)
    if argv is None and args._keeps_freed_memory:
        from herd_ros.process_memory import keep_freed_memory
        keep_freed_memory()
    try:
        with warnings.catch_warnings():
            # a reader's note (ids renamed, ...) as one line, not a Python warning
            warnings.showwarning = _note(args.verb)
            warnings.simplefilter('always', InputNote)
            status = args._run(args)
    except HerdInputError as exc:
        print(f'herd-ros {args.verb}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'herd-ros {args.verb}: interrupted', file=sys.stderr)
        return 130
    return int(status or 0)


if __name__ == '__main__':
    sys.exit(main())
