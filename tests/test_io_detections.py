"""Per-frame detection and tracker-result files: formats, folders, errors, atomicity."""

from __future__ import annotations

from pathlib import Path

import pytest

from egograph.core.errors import InputError
from egograph.core.types import Box, Detection, Prediction
from egograph.io.detections import (
    read_detection_dir,
    read_detection_file,
    read_results_dir,
    read_results_file,
    write_detection_dir,
    write_detection_file,
    write_results_dir,
    write_results_file,
)

T0 = 133_456_789_012_345_678  # an 18-digit HoloLens timestamp (100 ns ticks)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def assert_error_at(err: pytest.ExceptionInfo, path: Path, line: int | None) -> None:
    assert path.name in str(err.value)
    assert err.value.line == line
    if line is not None:
        assert f"{path.name}:{line}:" in str(err.value)


DETS = [
    Detection(3, Box(10.5, 20, 110.25, 220), 0.1234567891),
    Detection(0, Box(0, 0, 1280, 720), 1.0),
    Detection(12, Box(0.1234567891, 1e-7, 5, 6), 0.0),
]
PREDS = [
    Prediction(0, (0.1234567891, -2.5, 1.0), 0.9876543219),
    Prediction(4, (1e-9, 0.0, -12.75), 1.0),
]


# --------------------------------------------------------------------------- detections


def test_detection_file_round_trip_exact(tmp_path):
    p = tmp_path / f"{T0}.txt"
    write_detection_file(p, DETS)
    assert p.read_text().splitlines()[0] == "3 10.5 20 110.25 220 0.1234567891"
    assert read_detection_file(p) == DETS


def test_detection_file_5_6_7_columns(tmp_path):
    p = write(
        tmp_path / "d.txt",
        "1 10 20 30 40\n"  # no score -> 1.0
        "2 10 20 30 40 0.25\n"  # score
        "3 10 20 30 40 0.9 0.625\n",  # reference: det_conf similarity -> score = similarity
    )
    assert [(d.instance, d.score) for d in read_detection_file(p)] == [(1, 1.0), (2, 0.25), (3, 0.625)]
    assert all(d.box == Box(10, 20, 30, 40) for d in read_detection_file(p))


def test_detection_separators_are_equivalent(tmp_path):
    ws = write(tmp_path / "ws.txt", "3 10.5 20 110.25 220 0.5\n1 1 2 3 4 0.75\n")
    comma = write(tmp_path / "c.txt", "3,10.5,20,110.25,220,0.5\n1,1,2,3,4,0.75\n")
    mixed = write(tmp_path / "m.txt", "3, 10.5 ,20\t110.25  220,0.5\r\n1 ,1, 2,3 4 0.75,\n")
    assert read_detection_file(comma) == read_detection_file(ws)
    assert read_detection_file(mixed) == read_detection_file(ws)


def test_detection_xywh_vs_xyxy(tmp_path):
    p = write(tmp_path / "d.txt", "0 10 20 30 40 0.5\n")
    assert read_detection_file(p)[0].box == Box(10, 20, 30, 40)
    assert read_detection_file(p, box_format="xywh")[0].box == Box(10, 20, 40, 60)
    out = tmp_path / "out.txt"
    write_detection_file(out, [Detection(0, Box(10, 20, 40, 60), 0.5)], box_format="xywh")
    assert out.read_text() == "0 10 20 30 40 0.5\n"
    d = tmp_path / "dir"
    write_detection_dir(d, {T0: DETS}, box_format="xywh")
    assert read_detection_dir(d, box_format="xywh") == {T0: DETS}


def test_detection_dir_numeric_order_and_timestamps(tmp_path):
    d = tmp_path / "assoc"
    per_frame = {100: DETS[:1], 99: DETS[1:], T0: []}
    write_detection_dir(d, per_frame)
    got = read_detection_dir(d)
    assert list(got) == [99, 100, T0]
    assert got == per_frame
    # Every requested timestamp gets a key; a frame without a file has no detections.
    got = read_detection_dir(d, timestamps=[T0, 1000, 99])
    assert got == {99: DETS[1:], 1000: [], T0: []}
    assert list(got) == [99, 1000, T0]


def test_detection_dir_bad_file_name(tmp_path):
    d = tmp_path / "assoc"
    write(d / "100.txt", "0 1 2 3 4 0.5\n")
    write(d / ".100.txt.abc.tmp", "garbage")  # leftover temp file: ignored
    write(d / "frame_101.txt", "0 1 2 3 4 0.5\n")
    with pytest.raises(InputError) as err:
        read_detection_dir(d)
    assert_error_at(err, d / "frame_101.txt", None)
    with pytest.raises(InputError):
        read_detection_dir(tmp_path / "missing")


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("0 1 2 3 4 0.5\n\n0 1 2 3\n", 3, "expected 5 to 7 columns"),
        ("0 1 2 3 4 0.5 0.5 0.5\n", 1, "expected 5 to 7 columns"),
        ("# frame\nmug 1 2 3 4 0.5\n", 2, "instance"),
        ("0 1 2 3 4 0.5\n0 1 2 3 4 NaN\n", 2, "score"),
        ("0 1 2 3 4 0.5 inf\n", 1, "similarity"),
        ("0 10 2 3 4 0.5\n", 1, "x_max"),
        ("-1 1 2 3 4 0.5\n", 1, "negative"),
    ],
)
def test_detection_malformed_lines(tmp_path, text, line, fragment):
    p = write(tmp_path / f"{T0}.txt", text)
    with pytest.raises(InputError) as err:
        read_detection_file(p)
    assert_error_at(err, p, line)
    assert fragment in err.value.message


# --------------------------------------------------------------------------- results


def test_results_file_round_trip_exact(tmp_path):
    p = tmp_path / f"{T0}.txt"
    write_results_file(p, PREDS)
    assert p.read_text() == "0 0.1234567891 -2.5 1 0.9876543219\n4 1e-09 0 -12.75 1\n"
    assert read_results_file(p) == PREDS
    write_results_file(p, [])
    assert p.read_text() == ""
    assert read_results_file(p) == []


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("0 1 2 3 0.5\n0 1 2 3\n", 2, "expected 5 columns"),
        ("0 1 2 inf 0.5\n", 1, "z"),
        ("0 1 two 3 0.5\n", 1, "y"),
    ],
)
def test_results_malformed_lines(tmp_path, text, line, fragment):
    p = write(tmp_path / "1.txt", text)
    with pytest.raises(InputError) as err:
        read_results_file(p)
    assert_error_at(err, p, line)
    assert fragment in err.value.message


def test_results_dir_has_a_file_for_every_frame(tmp_path):
    d = tmp_path / "results"
    stamps = [T0, T0 + 333_333, 99, 100]
    write_results_dir(d, {T0 + 333_333: PREDS, 100: PREDS[:1]}, stamps)
    assert sorted(p.name for p in d.iterdir()) == sorted(f"{ts}.txt" for ts in stamps)
    assert (d / f"{T0}.txt").read_text() == ""
    assert (d / "99.txt").read_text() == ""
    got = read_results_dir(d)
    assert list(got) == [99, 100, T0, T0 + 333_333]
    assert got == {99: [], 100: PREDS[:1], T0: [], T0 + 333_333: PREDS}
    assert read_results_dir(d, timestamps=[100, 5]) == {5: [], 100: PREDS[:1]}


def test_results_dir_refuses_predictions_off_the_frame_list(tmp_path):
    with pytest.raises(ValueError):
        write_results_dir(tmp_path / "r", {7: PREDS}, [1, 2, 3])
    assert not (tmp_path / "r").exists()


def test_results_dir_replaces_old_folder_whole(tmp_path):
    d = tmp_path / "results"
    write_results_dir(d, {1: PREDS}, [1, 2])
    write_results_dir(d, {}, [3])
    assert [p.name for p in d.iterdir()] == ["3.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]  # no temp folders left


def test_a_3000_frame_results_folder_has_a_file_per_frame_and_reads_back(tmp_path):
    # (its speed is a benchmark's business, not a timed unit test's: the machines are shared)
    stamps = [T0 + 333_333 * i for i in range(3000)]
    per_frame = {ts: PREDS for ts in stamps[::2]}
    write_results_dir(tmp_path / "results", per_frame, stamps)
    assert len(list((tmp_path / "results").iterdir())) == 3000
    back = read_results_dir(tmp_path / "results", stamps)
    assert all(back[ts] == (list(PREDS) if i % 2 == 0 else []) for i, ts in enumerate(stamps))


# --------------------------------------------------------------------------- atomicity


class Exploding:
    """A record that fails while being formatted."""

    instance = 1
    box = Box(0, 0, 1, 1)

    @property
    def score(self):
        raise RuntimeError("boom")


def test_failed_write_keeps_existing_files(tmp_path):
    p = tmp_path / "100.txt"
    write_detection_file(p, DETS)
    before = p.read_text()
    with pytest.raises(RuntimeError, match="boom"):
        write_detection_file(p, [DETS[0], Exploding()])
    assert p.read_text() == before

    d = tmp_path / "assoc"
    write_detection_dir(d, {1: DETS, 2: DETS[:1]})
    snapshot = {f.name: f.read_text() for f in d.iterdir()}
    with pytest.raises(RuntimeError, match="boom"):
        write_detection_dir(d, {1: [], 2: [Exploding()]})
    assert {f.name: f.read_text() for f in d.iterdir()} == snapshot

    r = tmp_path / "results"
    write_results_dir(r, {1: PREDS}, [1, 2])
    snapshot = {f.name: f.read_text() for f in r.iterdir()}
    with pytest.raises(AttributeError):  # not a Prediction
        write_results_dir(r, {1: [object()]}, [1, 2])
    assert {f.name: f.read_text() for f in r.iterdir()} == snapshot
    assert sorted(x.name for x in tmp_path.iterdir()) == ["100.txt", "assoc", "results"]
