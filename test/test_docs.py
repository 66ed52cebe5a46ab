"""The documentation is self-contained: every relative link of README.md and docs/*.md resolves to a file of the
repository (and to a heading, where it names one), and no file of the repository cites documents that are not in
it (the design notes and the paper text the project was written from).

"""

from __future__ import annotations

import doctest
import math
import re
import subprocess
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Written in two pieces so that this file does not cite them itself.
FORBIDDEN = ('shared/' + 'design', 'shared/' + 'paper', 'CONTRACT' + '.md', 'MODEL' + '.md')

#: a Markdown inline link or image: [text](target) / ![alt](target); the target up to a space or ')'
LINK = re.compile(r'!?\[(?:[^\]\\]|\\.)*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
#: a reference-style definition: [label]: target
REF_DEF = re.compile(r'^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$', re.MULTILINE)
FENCE = re.compile(r'^\s{0,3}(```|~~~)')
HEADING = re.compile(r'^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$')
EXPLICIT_ANCHOR = re.compile(r'<a\s+(?:name|id)="([^"]+)"')


def repository_files() -> list[Path]:
    """Files of the repository: tracked plus new ones not ignored (what a clone would hold after a commit)."""
    out = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard', '-z'], cwd=ROOT,
                         check=True, capture_output=True).stdout.decode()
    return sorted({ROOT / p for p in out.split('\0') if p and (ROOT / p).is_file()})


def doc_files() -> list[Path]:
    """README.md and every Markdown file under docs/."""
    return [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('**/*.md'))]


def prose_lines(text: str) -> list[str]:
    """The lines of a Markdown text outside fenced code blocks."""
    lines, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, inline markup and punctuation dropped, spaces to hyphens.

    >>> slug('Two commands (fresh Debian 12 / Python 3.11 machine, PyPI only)')
    'two-commands-fresh-debian-12--python-311-machine-pypi-only'
    >>> slug('`gimbal-friction recover`')
    'gimbal-friction-recover'
    """
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', heading)  # a link in a heading keeps its text
    text = re.sub(r'<[^>]+>', '', text).lower()
    kept = []
    for ch in text:
        if ch in ' -_' or unicodedata.category(ch)[0] in 'LMN':
            kept.append(ch)
    return ''.join(kept).replace(' ', '-')


def anchors(path: Path) -> set[str]:
    """Every anchor a Markdown file defines: its headings' slugs (duplicates numbered) and explicit anchors."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    text = path.read_text(encoding='utf-8')
    for line in prose_lines(text):
        m = HEADING.match(line)
        if m:
            base = slug(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f'{base}-{n}')
    out.update(EXPLICIT_ANCHOR.findall(text))
    return out


def links(path: Path) -> list[str]:
    """The link targets of a Markdown file (outside fenced code and inline code spans)."""
    targets: list[str] = []
    for line in prose_lines(path.read_text(encoding='utf-8')):
        line = re.sub(r'`[^`]*`', '', line)
        targets += LINK.findall(line)
        targets += REF_DEF.findall(line)
    return targets


def broken_links(path: Path, root: Path = ROOT) -> list[str]:
    """The relative links of ``path`` that do not resolve inside ``root``: ``'target: why'`` per broken link."""
    bad = []
    for target in links(path):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target, re.IGNORECASE):  # http:, https:, mailto:, ...
            continue
        file_part, _, anchor = target.partition('#')
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            bad.append(f'{target}: no such file')
            continue
        try:
            dest.relative_to(root)
        except ValueError:
            bad.append(f'{target}: outside the repository')
            continue
        if anchor and dest.suffix == '.md' and anchor not in anchors(dest):
            bad.append(f'{target}: no heading with anchor #{anchor} in {dest.relative_to(root)}')
    return bad


def citations(paths: list[Path], root: Path = ROOT) -> list[str]:
    """``'file:line: name'`` (file relative to ``root``) for every line of a text file in ``paths`` that names a
    forbidden document."""
    found = []
    for path in paths:
        try:
            text = path.read_text(encoding='utf-8')
        except (UnicodeDecodeError, OSError):
            continue  # binary files (the sample bag) hold no citations
        for number, line in enumerate(text.splitlines(), 1):
            for name in FORBIDDEN:
                if name in line:
                    found.append(f'{path.relative_to(root)}:{number}: {name}')
    return found


def test_docs_folder_has_the_documents() -> None:
    names = {p.name for p in (ROOT / 'docs').glob('*.md')}
    assert {'README.md', 'model.md', 'ros.md', 'cli.md', 'closed-loop.md', 'CHANGELOG.md'} <= names


@pytest.mark.parametrize('path', doc_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path: Path) -> None:
    assert broken_links(path) == []


def test_docs_index_links_every_document() -> None:
    index = ROOT / 'docs' / 'README.md'
    linked = {(index.parent / t.partition('#')[0]).resolve() for t in links(index) if t.partition('#')[0]}
    missing = [p.name for p in (ROOT / 'docs').glob('*.md') if p.name != 'README.md' and p.resolve() not in linked]
    assert missing == []


def test_nothing_cites_documents_outside_the_repository() -> None:
    """Every file of the repository, README.md included."""
    assert citations(repository_files()) == []


def test_link_checker_reports_missing_files_and_anchors(tmp_path: Path) -> None:
    """The checker itself: a missing file, a missing heading and a link out of the tree are reported; good links
    (a file, a heading of the same file, a heading of another file, a URL, anything in code) are not."""
    docs = tmp_path / 'docs'
    docs.mkdir()
    (docs / 'other.md').write_text('# Other\n\n## The `x` rule (Eq. 9)\n\n## Other\n', encoding='utf-8')
    (tmp_path / 'outside.md').write_text('# Outside\n', encoding='utf-8')
    probe = docs / 'probe.md'
    probe.write_text('# Title here\n\n[a](other.md) [b](#title-here) [c](other.md#the-x-rule-eq-9) '
                     '[d](other.md#other-1) [e](https://example.org/x) `[f](in-code.md)`\n'
                     '```\n[g](inside-fence.md)\n```\n'
                     '[h](nope.md) [i](#nope) [j](other.md#nope) [k](../outside.md)\n', encoding='utf-8')
    assert broken_links(probe, root=docs) == [
        'nope.md: no such file',
        '#nope: no heading with anchor #nope in probe.md',
        'other.md#nope: no heading with anchor #nope in other.md',
        '../outside.md: outside the repository',
    ]


def test_citation_check_names_file_and_line(tmp_path: Path) -> None:
    cited = tmp_path / 'x.py'
    cited.write_text('ok\n# see ' + FORBIDDEN[3] + ' and ' + FORBIDDEN[0] + '/x\n', encoding='utf-8')
    (tmp_path / 'bin.dat').write_bytes(b'\xff\xfe' + FORBIDDEN[2].encode())
    assert citations([cited, tmp_path / 'bin.dat'], root=tmp_path) == [
        f'x.py:2: {FORBIDDEN[0]}', f'x.py:2: {FORBIDDEN[3]}']


def test_ros_page_documents_every_parameter() -> None:
    """Every model parameter and every setting of the three nodes has a row in docs/ros.md with its default."""
    import dataclasses

    from gimbal_friction.config.node_settings import EstimatorNodeSettings, FeedforwardNodeSettings, LoggerSettings
    from gimbal_friction.estimation.estimator import EstimatorSettings
    from gimbal_friction.feedforward.rule import FeedforwardSettings
    from gimbal_friction.physics.params import parameter_specs

    rows = {}
    for line in (ROOT / 'docs' / 'ros.md').read_text(encoding='utf-8').splitlines():
        m = re.match(r'\| `([a-z0-9_]+)` \| [a-z\[\]]+ \| ([^|]+) \|', line)
        if m:
            rows.setdefault(m.group(1), set()).add(m.group(2).strip())
    expected = {s['name']: s['default'] for s in parameter_specs()}
    for cls in (FeedforwardSettings, FeedforwardNodeSettings, EstimatorSettings, EstimatorNodeSettings,
                LoggerSettings):
        expected.update({f.name: f.default for f in dataclasses.fields(cls)})
    from gimbal_friction.config.node_settings import FEEDFORWARD_PREFIXED
    for prefix, cls in FEEDFORWARD_PREFIXED:
        expected.update({prefix + f.name: f.default for f in dataclasses.fields(cls)})

    def same(documented: str, default: object) -> bool:
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            return documented.strip('`"').lower() == str(default).lower()
        try:
            return math.isclose(float(documented), float(default), rel_tol=1e-5)
        except ValueError:
            return False

    missing = sorted(set(expected) - set(rows))
    wrong = sorted(f'{name}: documented {rows[name]}, default {default!r}' for name, default in expected.items()
                   if name in rows and not any(same(d, default) for d in rows[name]))
    assert (missing, wrong) == ([], [])


def test_cli_page_shows_each_subcommands_help(monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """docs/cli.md shows each subcommand's ``--help`` verbatim (as printed 116 columns wide). After changing an option,
    run ``.venv/bin/python scripts/cli_reference.py``."""
    from gimbal_friction.cli.main import main

    text = (ROOT / 'docs' / 'cli.md').read_text(encoding='utf-8')
    blocks = {m.group(1): m.group(0) for m in
              re.finditer(r'```text\nusage: gimbal-friction (\S+).*?\n```', text, re.DOTALL)}
    monkeypatch.setenv('COLUMNS', '116')
    stale = []
    for sub in ('model', 'calibrate-kt', 'synth-bag', 'replay', 'report', 'refit', 'export', 'fleet', 'recover',
                'loop-study'):
        with pytest.raises(SystemExit) as exit_info:
            main([sub, '--help'])
        assert exit_info.value.code == 0
        shown = capsys.readouterr().out.rstrip()
        if blocks.get(sub) != f'```text\n{shown}\n```':
            stale.append(sub)
    assert stale == []


def test_model_page_example_runs() -> None:
    result = doctest.testfile(str(ROOT / 'docs' / 'model.md'), module_relative=False,
                              optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 3 and result.failed == 0
