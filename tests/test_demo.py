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


@pytest.mark.slow
def test_the_demo_ends_with_the_path_of_its_pictures(tmp_path):
    out = tmp_path / "demo"
    p = subprocess.run([str(VENV_BIN / "egograph"), "demo", str(out), "--frames", "150", "--seed", "2"],
                       capture_output=True, text=True, timeout=1200, env={**os.environ, "COLUMNS": "100"})
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.splitlines()
    index = out / "plots" / "index.html"
    assert lines[-1] == str(index.resolve())
    # the set-up and the steps before the tables stay short (stderr: progress bars, warnings)
    first_table = next(i for i, line in enumerate(lines) if "IT3DEgo evaluation" in line)
    assert first_table + len(p.stderr.splitlines()) < 120, (first_table, p.stderr[-2000:])
    # per detection set, whether the graph beats every baseline at every threshold, and if not why
    verdicts = [line for line in lines if line.startswith(("graph: ", "graph-causal: "))]
    assert len(verdicts) == 4, verdicts
    for i, line in enumerate(lines):
        if line.startswith(("graph: below", "graph-causal: below")):
            assert lines[i + 1].startswith("  why: "), lines[i:i + 2]
    # per detection set, AP per threshold and whether each egograph tracker's curve passes every baseline's point
    curves = [line for line in lines if line.startswith(("graph (robust lift): curve", "graph-causal (robust lift): curve"))]
    assert len(curves) == 4, curves
    assert sum(line.startswith("average precision over confidence") for line in lines) == 2
    images = page_images(index)
    want = {"metrics.png", "curves.png"} | {f"{kind}_{re.sub(r'[^A-Za-z0-9_.-]+', '_', row).strip('._')}.png"
                              for row in DEMO_ROWS for kind in ("timeline", "map")}
    assert set(images) == want, set(images) ^ want
    for name in images:
        data = (index.parent / name).read_bytes()
        w, h = png_size(data)
        assert decode_png(data).size == (w, h) and w >= 300 and h >= 150, name
    text = index.read_text()
    for row in DEMO_ROWS:  # the evaluation table names every tracker
        assert row in text, row
