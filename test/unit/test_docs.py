"""Every document the project cites exists: each ``docs/...`` path named in the code, the
README and docs/, each ``test/...py`` or ``bench/...py`` file the README and docs/ name (so
that a moved test or script does not leave a stale reference), and each relative link (with its
#anchor) in the README and docs/."""
from pathlib import Path
import re

REPO = Path(__file__).resolve().parents[2]

#: Documents cited before the work that writes them has landed, and which work that is. A
#: pending document may exist already; once it does, its entry can go.
PENDING: dict = {}

#: Where the code and the documents are (test/data holds copies of outside files as they are).
CODE_GLOBS = ('mantis_rig/**/*.py', 'mantis_sim/**/*.py', 'bench/**/*.py', 'launch/*.py',
              'scripts/*', 'test/**/*.py', 'setup.py', 'setup.cfg', 'package.xml', 'ruff.toml')
DOC_GLOBS = ('README.md', 'docs/**/*.md')

DOCS_PATH = re.compile(r'(?<![\w-])docs/[\w./-]*')
SOURCE_PATH = re.compile(r'(?<![\w./-])(?:test|bench)/[\w/-]*\.py\b')
LINK = re.compile(r'\]\(([^)\s]+)\)')


def _files(globs):
    seen = set()
    for pattern in globs:
        for path in sorted(REPO.glob(pattern)):
            if path.is_file() and 'test/data' not in path.relative_to(REPO).as_posix() \
                    and path not in seen and path != Path(__file__).resolve():   # its examples
                seen.add(path)
                yield path


def _docs_paths(text):
    """The ``docs/...`` paths a text names, without trailing punctuation."""
    for match in DOCS_PATH.finditer(text):
        path = match.group(0).rstrip('.,:;')
        if path.endswith('...'):
            continue
        yield path


def test_every_test_and_bench_file_the_documents_name_exists():
    missing = []
    for path in _files(DOC_GLOBS):
        for cited in sorted(set(SOURCE_PATH.findall(path.read_text()))):
            if not (REPO / cited).is_file():
                missing.append(f'{path.relative_to(REPO)}: {cited}')
    assert not missing, 'named but not in the repository:\n' + '\n'.join(missing)


def _slug(heading):
    """GitHub's anchor for a markdown heading."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def _anchors(md_path):
    return {_slug(line.lstrip('#')) for line in md_path.read_text().splitlines()
            if re.match(r'#{1,6} ', line)}


def test_every_docs_path_named_in_the_code_and_the_documents_exists():
    missing = []
    for path in _files(CODE_GLOBS + DOC_GLOBS):
        for cited in sorted(set(_docs_paths(path.read_text(errors='replace')))):
            if not (REPO / cited).exists() and cited not in PENDING:
                missing.append(f'{path.relative_to(REPO)}: {cited}')
    assert not missing, 'cited but not in the repository:\n' + '\n'.join(missing)


def test_every_relative_link_in_the_readme_and_docs_resolves():
    broken = []
    for path in _files(DOC_GLOBS):
        for target in LINK.findall(path.read_text()):
            if re.match(r'[a-z]+:', target):
                continue                                 # http(s):, mailto:
            file_part, _, anchor = target.partition('#')
            resolved = (path.parent / file_part).resolve() if file_part else path
            cited = resolved.relative_to(REPO).as_posix() if resolved.is_relative_to(REPO) \
                else str(resolved)
            if not resolved.exists():
                if cited not in PENDING:
                    broken.append(f'{path.relative_to(REPO)}: {target}')
            elif anchor and resolved.suffix == '.md' and anchor not in _anchors(resolved):
                broken.append(f'{path.relative_to(REPO)}: {target} (no such heading)')
    assert not broken, 'links that lead nowhere:\n' + '\n'.join(broken)


def test_the_checks_see_a_missing_document_and_a_missing_heading(tmp_path):
    """The two checks above would fail on a document or a heading that is not there."""
    assert list(_docs_paths('see `docs/no_such.md`, and docs/rig.md.')) == \
        ['docs/no_such.md', 'docs/rig.md']
    assert SOURCE_PATH.findall('`test/unit/test_sim.py`, bench/bench_trial.py; x/test/y.py') == \
        ['test/unit/test_sim.py', 'bench/bench_trial.py']
    doc = tmp_path / 'a.md'
    doc.write_text('# The fuzz suite\'s long profile\n## On a ROS 2 Jazzy install\n')
    assert _anchors(doc) == {'the-fuzz-suites-long-profile', 'on-a-ros-2-jazzy-install'}


def test_the_readme_is_a_short_document():
    lines = (REPO / 'README.md').read_text().splitlines()
    assert len(lines) <= 150, f'README.md has {len(lines)} lines (at most 150; the rest: docs/)'
