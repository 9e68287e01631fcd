"""``egograph demo`` ends in pictures: after its tables it draws every tracker's results with
``egograph plot``, and its last line is the path of ``index.html``, whose every picture exists and is
a PNG that decodes."""

from __future__ import annotations

import html.parser
import io
import os
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

VENV_BIN = Path(sys.executable).parent
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PROGRESS = re.compile(r"\|\s*\d+/\d+ \[")   # a progress bar's update: "...| 24/150 [00:04<00:24, ..."
# the demo's rows: per detection set, memory and kf on reference lifting, and memory, kf, graph,
# graph-causal on robust lifting
DEMO_ROWS = [f"{s} {t} ({m} lift)" for s in ("svoe", "mvpe")
             for m, ts in (("reference", ("memory", "kf")), ("robust", ("memory", "kf", "graph", "graph-causal")))
             for t in ts]


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG, after checking its signature and its IHDR chunk (length, type, CRC);
    ValueError when it is not one."""
    if data[:8] != PNG_SIGNATURE:
        raise ValueError("no PNG signature")
    length, kind = struct.unpack(">I4s", data[8:16])
    if kind != b"IHDR" or length != 13:
        raise ValueError("the first chunk is not a 13-byte IHDR")
    body, crc = data[16:29], struct.unpack(">I", data[29:33])[0]
    if zlib.crc32(b"IHDR" + body) != crc:
        raise ValueError("IHDR CRC mismatch")
    w, h = struct.unpack(">II", body[:8])
    if w == 0 or h == 0:
        raise ValueError("empty image")
    return w, h


def decode_png(data: bytes):
    """The pixels (PIL decodes every chunk, so a truncated or corrupt file fails)."""
    from PIL import Image

    im = Image.open(io.BytesIO(data))
    im.load()
    return im


class _Refs(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.images: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images += [v for k, v in attrs if k == "src" and v]


def page_images(index: Path) -> list[str]:
    p = _Refs()
    p.feed(index.read_text())
    return p.images


def test_png_checks_fail_on_broken_files(tmp_path):
    import numpy as np
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (40, 60, 3), np.uint8)).save(buf, format="PNG")
    good = buf.getvalue()
    assert png_size(good) == (60, 40) and decode_png(good).size == (60, 40)
    with pytest.raises(ValueError, match="signature"):
        png_size(b"GIF89a" + good[6:])
    with pytest.raises(ValueError, match="CRC"):
        png_size(good[:20] + bytes([good[20] ^ 1]) + good[21:])
    with pytest.raises(OSError):
        decode_png(good[:len(good) // 2])


def test_demo_help_and_readme_say_how_long_the_demo_and_the_tests_take():
    from egograph.cli.main import DEMO_TIMES

    assert re.search(r"demo\.sh took \d+ min .*test\.sh \d+ min", DEMO_TIMES)
    p = subprocess.run([str(VENV_BIN / "egograph"), "demo", "--help"], capture_output=True, text=True, timeout=120)
    flat = lambda t: " ".join(t.split())  # noqa: E731
    assert p.returncode == 0 and flat(DEMO_TIMES) in flat(p.stdout)
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert flat(DEMO_TIMES.replace(" `egograph demo --help` says the same.", "")) in flat(readme)


def run_demo(out: Path, frames: int, *extra: str) -> list[str]:
    p = subprocess.run([str(VENV_BIN / "egograph"), "demo", str(out), "--frames", str(frames), "--seed", "2", *extra],
                       capture_output=True, text=True, timeout=1200, env={**os.environ, "COLUMNS": "100"})
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.splitlines()
    # the set-up and the steps before the tables stay short (stderr: warnings; the progress bars'
    # updates, one line each in a log and one line a bar on a terminal, are not counted)
    first_table = next(i for i, line in enumerate(lines) if "IT3DEgo evaluation" in line)
    other = [line for line in p.stderr.splitlines() if line.strip() and not PROGRESS.search(line)]
    assert first_table + len(other) < 120, (first_table, other[-20:])
    return lines


def check_demo(out: Path, lines: list[str], sets: list[str], pv_frames: bool) -> None:
    """The demo's verdicts, curves and pictures for the detection sets ``sets`` it tracked (with the
    sheet of PV frames around the breaks when the recording has PV images)."""
    index = out / "plots" / "index.html"
    assert lines[-1] == str(index.resolve())
    # per detection set, whether the graph beats every baseline at every threshold, and if not why
    verdicts = [line for line in lines if line.startswith(("graph: ", "graph-causal: "))]
    assert len(verdicts) == 2 * len(sets), verdicts
    for i, line in enumerate(lines):
        if line.startswith(("graph: below", "graph-causal: below")):
            assert lines[i + 1].startswith("  why: "), lines[i:i + 2]
    # per detection set, AP per threshold and whether each egograph tracker's curve passes every baseline's point
    curves = [line for line in lines if line.startswith(("graph (robust lift): curve", "graph-causal (robust lift): curve"))]
    assert len(curves) == 2 * len(sets), curves
    assert sum(line.startswith("average precision over confidence") for line in lines) == len(sets)
    rows = [row for row in DEMO_ROWS if row.split()[0] in sets]
    images = page_images(index)
    want = {"metrics.png", "curves.png"} | ({"pv_sheet.png"} if pv_frames else set()) | {f"{kind}_{re.sub(r'[^A-Za-z0-9_.-]+', '_', row).strip('._')}.png"
                              for row in rows for kind in ("timeline", "map")}
    assert set(images) == want, set(images) ^ want
    for name in images:
        data = (index.parent / name).read_bytes()
        w, h = png_size(data)
        assert decode_png(data).size == (w, h) and w >= 300 and h >= 150, name
    text = index.read_text()
    for row in rows:  # the evaluation table names every tracker
        assert row in text, row


@pytest.mark.slow
def test_the_demo_detects_in_device_like_frames_and_ends_with_the_path_of_its_pictures(tmp_path):
    out = tmp_path / "demo"
    lines = run_demo(out, 60)   # 60 frames (2 s of recording): render and detect make this the suite's longest test
    assert any("device-like PV frames" in line for line in lines)
    # egograph detect ran on the rendered frames, both enrollments, and said what it found
    for det_set in ("SVOE", "MVPE"):
        summary = [line for line in lines if line.startswith(f"{det_set}: 60 PV frames, ")]
        assert len(summary) == 1, det_set
    assert sorted(p.name for p in (out / "detections").iterdir()) == ["mvpe", "proposal_embeddings.npz", "svoe"]
    assert len(list((out / "recording" / "synth_seq" / "pv").glob("*.png"))) == 60
    # a set in which nothing was found, or nothing could be lifted, is said so and not tracked; the
    # others are tracked and scored
    empty = {s for s in ("svoe", "mvpe") if f"{s.upper()}: no instance found in any PV frame; its trackers are not run" in lines}
    unlifted = {s for s in ("svoe", "mvpe") if any(line.startswith(f"{s.upper()}: none of its detections could be lifted "
                                                                  "to 3D (") and line.endswith("; its trackers are not run")
                                                  for line in lines)}
    tracked = [s for s in ("svoe", "mvpe") if s not in empty | unlifted]
    assert tracked, "seed 2's enrollments find and lift their instances in some frames"
    for det_set in tracked:
        assert any(f.stat().st_size for f in (out / "detections" / det_set).glob("*.txt"))
    for det_set in unlifted:
        assert not (out / "results").exists() or not list((out / "results").glob(f"{det_set}_*"))
    # SVOE is verified (configs/frontend-svoe.yaml): its score is a probability at or above the
    # operating point, det_conf says whether local features verified it
    rows = [line.split() for f in (out / "detections" / "svoe").glob("*.txt") for line in f.read_text().splitlines()]
    assert rows or "svoe" not in tracked
    assert all(float(r[5]) in (0.0, 1.0) and 0.45 <= float(r[6]) <= 1.0 for r in rows)
    check_demo(out, lines, tracked, pv_frames=True)


@pytest.mark.slow
def test_the_simulated_demo_tracks_both_detection_sets(tmp_path):
    out = tmp_path / "demo"
    lines = run_demo(out, 150, "--simulated")   # at 90 frames seed 2's simulated detections are all false
    assert not (out / "detections").exists()
    assert not list((out / "recording" / "synth_seq" / "pv").glob("*.png"))   # no RGB rendered
    check_demo(out, lines, ["svoe", "mvpe"], pv_frames=False)


@pytest.mark.slow
def test_a_demo_whose_detections_give_no_answer_says_so_and_exits_2(tmp_path):
    """Seed 2's 90 simulated frames: SVOE's one detection has no depth, MVPE's 13 all score below the
    threshold. Each set is said so and left out; with none left the demo ends with exit 2 and one line,
    not with tables of nothing and a failing picture step."""
    out = tmp_path / "demo"
    p = subprocess.run([str(VENV_BIN / "egograph"), "demo", str(out), "--frames", "90", "--seed", "2", "--simulated"],
                       capture_output=True, text=True, timeout=600, env={**os.environ, "COLUMNS": "100"})
    assert p.returncode == 2, p.stderr[-3000:]
    assert "SVOE: none of its detections could be lifted to 3D" in p.stdout
    assert ("MVPE: no tracker answered any PV frame (0 of its 13 lifted detections score at least "
            "track.score_threshold 0.6); it is left out of the evaluation and the pictures") in " ".join(p.stdout.split())
    assert "IT3DEgo evaluation" not in p.stdout and not (out / "plots").exists()
    errors = [line for line in p.stderr.splitlines() if line.startswith("egograph: error:")]
    assert len(errors) == 1 and "nothing to score" in errors[0] and "--simulated` tracks" not in errors[0]
    assert "Traceback" not in p.stderr
