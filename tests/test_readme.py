"""The README's commands run as written.

Every shell block of README.md carries a marker (an HTML comment on the line before it, explained at
the top of the README): ``runnable`` blocks are run from a copy of the repository with .venv's
``egograph`` on the PATH; ``runnable: slow`` blocks (the demo, the full test suite) are checked by
``bash -n`` and every repository path they name must exist; ``example: ...`` blocks need the
IT3DEgo release, so their ``egograph`` lines go through the command-line parser, and the worked
example runs on a synthetic recording laid out as the release. Configuration blocks of the docs
(``<!-- config ... -->``) load as egograph configurations.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
MARKER = re.compile(r"^<!--\s*(runnable(?::\s*slow)?|example:[^>]*?|config:[^>]*?)\s*-->\s*$")
FENCE = re.compile(r"^```(\w*)")
VENV_BIN = Path(sys.executable).parent


@dataclass
class Block:
    marker: str | None   # "runnable", "runnable: slow", "example: ...", "config: ..." or None
    lang: str
    text: str
    line: int            # 1-based line of the opening fence

    @property
    def kind(self) -> str | None:
        """"runnable", "runnable: slow", "example", "config" or None."""
        if self.marker is None:
            return None
        if self.marker.startswith("runnable"):
            return "runnable: slow" if "slow" in self.marker else "runnable"
        return self.marker.split(":")[0]


def blocks(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown file, each with the marker on the line before it."""
    lines = path.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m:
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            prev = lines[i - 1] if i > 0 else ""
            mk = MARKER.match(prev.strip())
            out.append(Block(mk.group(1).strip() if mk else None, m.group(1), "\n".join(lines[i + 1:j]) + "\n", i + 1))
            i = j + 1
        else:
            i += 1
    return out


def shell_blocks(path: Path = README) -> list[Block]:
    return [b for b in blocks(path) if b.lang in ("bash", "sh", "shell")]


def test_readme_is_short():
    n = len(README.read_text().splitlines())
    assert n <= 300, f"README.md has {n} lines; move detail to docs/"


def test_every_shell_block_of_the_readme_is_marked():
    bl = shell_blocks()
    assert {b.kind for b in bl} >= {"runnable", "runnable: slow", "example"}
    for b in bl:
        assert b.kind in ("runnable", "runnable: slow", "example"), \
            f"README.md:{b.line}: a shell block without a <!-- runnable --> / <!-- runnable: slow --> / " \
            "<!-- example: ... --> marker on the line before it"


def test_the_marker_parser_sees_a_missing_marker(tmp_path):
    md = tmp_path / "x.md"
    md.write_text("text\n\n```bash\nls\n```\n<!-- runnable -->\n```bash\nls\n```\n<!-- example: data -->\n```sh\nls\n```\n")
    assert [b.kind for b in shell_blocks(md)] == [None, "runnable", "example"]


def _bash_n(b: Block) -> None:
    p = subprocess.run(["bash", "-n"], input=b.text, capture_output=True, text=True)
    assert p.returncode == 0, f"README.md:{b.line}: bash -n: {p.stderr}"


REPO_PATH = re.compile(r"(?<![\w/.-])((?:tools|docs|tests|configs|egograph|\.ci)/[\w./-]+)")


def test_slow_blocks_parse_and_name_files_that_exist():
    slow = [b for b in shell_blocks() if b.kind == "runnable: slow"]
    assert slow
    for b in slow:
        _bash_n(b)
        for path in REPO_PATH.findall(b.text):
            assert (REPO / path).exists(), f"README.md:{b.line}: {path} does not exist"


def test_the_readme_picture_is_a_png_the_demo_draws():
    """The picture the README shows is committed, a valid PNG, and the command that regenerates
    it copies a file the demo writes (the demo's rows are "<set> <tracker> (<mode> lift)")."""
    from egograph.eval.plots import slug

    from test_demo import png_size

    text = README.read_text()
    pics = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", text)
    assert pics == ["docs/img/demo-timeline.png"]
    w, h = png_size((REPO / pics[0]).read_bytes())
    assert w >= 400 and h >= 200
    cp = re.search(r'cp "out/demo/plots/([^"]+)" docs/img/demo-timeline\.png', text)
    assert cp and cp.group(1) == f"timeline_{slug('mvpe graph (robust lift)')}.png"


def _egograph_parser_shim(tmp_path: Path) -> Path:
    """A folder with an ``egograph`` that only parses its arguments with egograph's own parser."""
    shim = tmp_path / "shim"
    shim.mkdir()
    exe = shim / "egograph"
    exe.write_text(f"#!{sys.executable}\nimport sys\nfrom egograph.cli.main import build_parser\n"
                   "build_parser().parse_args(sys.argv[1:])\n")
    exe.chmod(0o755)
    return shim


def test_example_blocks_parse_with_the_command_line_parser(tmp_path):
    examples = [b for b in shell_blocks() if b.kind == "example"]
    assert examples
    env = {**os.environ, "PATH": f"{_egograph_parser_shim(tmp_path)}{os.pathsep}{os.environ['PATH']}"}
    for b in examples:
        _bash_n(b)
        assert "egograph " in b.text
        p = subprocess.run(["bash", "-euo", "pipefail", "-c", b.text], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=120)
        assert p.returncode == 0, f"README.md:{b.line}: {p.stderr}"


def test_the_parser_shim_refuses_a_wrong_option(tmp_path):
    """The check above can fail: a misspelt option is refused."""
    env = {**os.environ, "PATH": f"{_egograph_parser_shim(tmp_path)}{os.pathsep}{os.environ['PATH']}"}
    p = subprocess.run(["bash", "-c", "egograph track REC --tracker graph --detections svoe --out X --lagg 2"], env=env,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "unrecognized arguments: --lagg" in p.stderr


def test_config_blocks_of_the_docs_load(tmp_path):
    """The encoder configurations docs/frontend.md shows are configurations egograph reads, and
    set what they say they set."""
    import yaml

    from egograph.core.config import load_config
    from egograph.steps.settings import EgographConfig

    found = 0
    for md in sorted((REPO / "docs").glob("*.md")):
        for b in blocks(md):
            if b.kind != "config":
                continue
            found += 1
            f = tmp_path / f"block{found}.yaml"
            f.write_text(b.text)
            cfg = load_config(EgographConfig, f)
            for key, value in yaml.safe_load(b.text)["frontend"].items():
                assert getattr(cfg.frontend, key) == value, (md.name, b.line, key)
    assert found >= 2


def _repo_copy(dst: Path) -> Path:
    """The tracked files of the checkout (as a fresh clone has them), with .venv linked in."""
    files = subprocess.run(["git", "-C", str(REPO), "ls-files", "-z"], capture_output=True, text=True, check=True)
    for rel in files.stdout.split("\0"):
        if not rel:
            continue
        src, out = REPO / rel, dst / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            out.symlink_to(os.readlink(src))
        elif src.is_file():
            shutil.copy2(src, out)
    (dst / ".venv").symlink_to(VENV_BIN.parent)
    return dst


@pytest.mark.slow
def test_runnable_blocks_run_from_a_copy_of_the_repository(tmp_path):
    runnable = [b for b in shell_blocks() if b.kind == "runnable"]
    assert runnable
    repo = _repo_copy(tmp_path / "egograph")
    env = {**os.environ, "EGOGRAPH_CACHE": str(tmp_path / "cache")}
    for b in runnable:
        p = subprocess.run(["bash", "-euo", "pipefail", "-c", b.text], cwd=repo, env=env, capture_output=True,
                           text=True, timeout=900)
        assert p.returncode == 0, f"README.md:{b.line}: exit {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    assert (repo / "out" / "tiny-plots" / "index.html").is_file()


@pytest.mark.slow
def test_the_worked_example_runs_on_a_recording_laid_out_as_the_release(tmp_path):
    """The README's release example, as written but for the DATA folder: a synthetic recording with
    PV frames, laid out as the IT3DEgo release lays it out (tests/test_release_layout.py)."""
    from conftest import make_recording
    from test_release_layout import SEQ, release_layout

    (example,) = [b for b in shell_blocks() if b.kind == "example"]
    src = make_recording(tmp_path / "synthetic", 3, "frames=30", f"sequence={SEQ}")
    data = release_layout(src, tmp_path / "release")
    lines = example.text.splitlines()
    assert lines[0].startswith("DATA=") and f"SEQ={SEQ}" in lines
    script = "\n".join([f"DATA={data}", *lines[1:]]) + "\n"
    env = {**os.environ, "PATH": f"{VENV_BIN}{os.pathsep}{os.environ['PATH']}",
           "EGOGRAPH_CACHE": str(tmp_path / "cache")}
    p = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=900)
    assert p.returncode == 0, f"exit {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    out = tmp_path / "out" / SEQ
    assert (out / "graph" / "intervals.json").is_file() and (out / "plots" / "index.html").is_file()
    assert len(list((out / "dets").glob("*.txt"))) == 30


def _anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    keep = "".join(c for c in heading.strip().lower() if c.isalnum() or c in " -_")
    return keep.replace(" ", "-")


def test_links_between_the_docs_resolve():
    """Every relative link of README.md and docs/*.md names a file that exists and, with #anchor, one
    of its headings."""
    pages = [README, *sorted((REPO / "docs").glob("*.md"))]
    anchors = {}
    for p in pages:
        text = re.sub(r"```.*?```", "", p.read_text(), flags=re.S)
        anchors[p.resolve()] = {_anchor(h) for h in re.findall(r"^#+\s+(.+)$", text, flags=re.M)}
    n = 0
    for p in pages:
        text = re.sub(r"```.*?```", "", p.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (p.parent / path).resolve() if path else p.resolve()
            assert dest.exists(), f"{p.name}: link to {target}: no such file"
            if anchor:
                assert anchor in anchors.get(dest, set()), f"{p.name}: link to {target}: no such heading"
            n += 1
    assert n >= 20
