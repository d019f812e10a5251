"""The documentation (issue 28): ``doc/`` builds with Sphinx with no warning, every node
parameter and every command-line option is in the built pages, and the README stays a
front page (at most 200 lines)."""
import re
import warnings
from html import unescape

import pytest
from conftest import REPO

sphinx = pytest.importorskip('sphinx.cmd.build', reason='sphinx is a dev dependency (make setup)')


@pytest.fixture(scope='module')
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp('html')
    with warnings.catch_warnings():         # Sphinx's deprecation notices to extensions
        warnings.simplefilter('ignore')
        status = sphinx.build_main(['-W', '--keep-going', '-q', '-b', 'html',
                                    str(REPO / 'doc'), str(out)])
    assert status == 0, 'the documentation has warnings (rebuild: make docs)'
    text = {}
    for page in out.rglob('*.html'):
        body = re.sub(r'<[^>]+>', ' ', page.read_text())
        text[str(page.relative_to(out))] = unescape(body)
    return text


def test_every_node_parameter_is_documented(built):
    from herd_ros.params import NODES, table
    from herd_ros.params.controller import FLOCKING_TABLE, HERDING_TABLE
    page = built['_generated/parameters.html']
    for t in [table(n) for n in NODES] + [FLOCKING_TABLE, HERDING_TABLE]:
        for name, spec in t.params.items():
            assert name in page and spec.description.split()[0] in page, (t.node, name)


def test_every_command_line_option_is_documented(built):
    from herd_ros.cli.main import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == '_SubParsersAction')
    page = built['_generated/cli.html']
    for verb, p in sub.choices.items():
        assert f'herd-ros {verb}' in page, verb
        for action in p._actions:
            for option in action.option_strings:
                assert option in page, (verb, option)


def test_every_page_is_reachable_and_the_readme_is_short(built):
    for name in ('gps_ingest', 'estimator', 'controller', 'herding', 'method', 'formats',
                 'real_herds', 'results', 'api', 'getting_started'):
        assert f'{name}.html' in built, name
    readme = (REPO / 'README.md').read_text().splitlines()
    assert len(readme) <= 200, len(readme)
    for page in ('doc/getting_started.md', 'doc/formats.md', 'doc/results.md'):
        assert page in '\n'.join(readme), page
