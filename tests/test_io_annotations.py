"""IT3DEgo annotation readers/writers: round trips, separators, box formats, errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from egograph.core.errors import InputError
from egograph.core.types import Box
from egograph.io.annotations import (
    Annotations,
    CenterAnnotation,
    MotionInterval,
    SvoeEnrollment,
    load_annotations,
    read_bbox_annot,
    read_bbox_annot_dir,
    read_centers,
    read_labels,
    read_motion_states,
    read_mvpe_photos,
    read_svoe,
    save_annotations,
    write_bbox_annot,
    write_bbox_annot_dir,
    write_centers,
    write_labels,
    write_motion_states,
    write_svoe,
)
from egograph.io.textio import iter_rows, parse_float, parse_int, split_fields

T0 = 133_456_789_012_345_678  # an 18-digit HoloLens timestamp (100 ns ticks)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def assert_error_at(err: pytest.ExceptionInfo, path: Path, line: int | None) -> None:
    msg = str(err.value)
    assert path.name in msg
    assert err.value.line == line
    if line is not None:
        assert f"{path.name}:{line}:" in msg


def sample_annotations() -> Annotations:
    return Annotations(
        labels=["mug", "red bottle", "keyboard"],
        centers=[
            CenterAnnotation(T0, T0 + 5_000_000, 0, (0.1234567891, -1.5, 2.0), 0),
            CenterAnnotation(T0 + 5_000_001, T0 + 9_000_000, 0, (1.0, 1e-9, -3.25), 1),
            CenterAnnotation(T0, T0 + 9_000_000, 2, (3.0, 0.0, 0.7071067811865476), 0),
        ],
        motion=[MotionInterval(0, T0, T0 + 4_000_000), MotionInterval(2, T0, T0 + 9_000_000)],
        boxes={
            0: [(T0, Box(10.5, 20.25, 100.0, 200.125)), (T0 + 1_666_665, Box(0.1234567891, 0, 1279, 719))],
            2: [(T0 + 3, Box(5, 6, 7, 8))],
        },
        svoe=[SvoeEnrollment(0, T0, Box(10.5, 20.25, 100.0, 200.125)), SvoeEnrollment(2, T0 + 3, Box(5, 6, 7, 8))],
    )


# --------------------------------------------------------------------------- text helpers


def test_split_fields_accepts_commas_whitespace_and_mixtures():
    assert split_fields("1, 2 ,3") == ["1", "2", "3"]
    assert split_fields("1\t2  3") == ["1", "2", "3"]
    assert split_fields(" 1,2,3, \r") == ["1", "2", "3"]


def test_iter_rows_skips_blank_and_comment_lines_and_counts_physical_lines(tmp_path):
    p = write(tmp_path / "t.txt", "# header\n\n1 2\n   \n3,4\n")
    assert list(iter_rows(p, 2)) == [(3, ["1", "2"]), (5, ["3", "4"])]


def test_parse_int_is_exact_and_parse_float_is_finite(tmp_path):
    p = tmp_path / "f.txt"
    assert parse_int("133456789012345678", p, 1, "ts") == 133456789012345678
    assert parse_int("3.0", p, 1, "id") == 3
    with pytest.raises(InputError, match="id"):
        parse_int("3.5", p, 1, "id")
    with pytest.raises(InputError, match="ts"):
        parse_int("abc", p, 1, "ts")
    assert parse_float("0.1234567891", p, 1, "x") == 0.1234567891
    for bad in ("nan", "inf", "-Infinity", "x"):
        with pytest.raises(InputError, match=r"f\.txt:1: x"):
            parse_float(bad, p, 1, "x")


# --------------------------------------------------------------------------- Box


def test_box_properties_and_xywh():
    b = Box.from_xywh(10, 20, 30, 40)
    assert b == Box(10, 20, 40, 60)
    assert b.to_xywh() == (10, 20, 30, 40)
    assert (b.width, b.height, b.area, b.center) == (30, 40, 1200, (25, 40))
    with pytest.raises(ValueError):
        Box(5, 0, 4, 1)
    with pytest.raises(ValueError):
        Box.from_xywh(0, 0, -1, 1)
    with pytest.raises(ValueError):
        Box(0, 0, float("nan"), 1)


def test_box_clip():
    assert Box(-10, -5, 50, 30).clip(1280, 720) == Box(0, 0, 50, 30)
    assert Box(1200, 700, 1300, 800).clip(1280, 720) == Box(1200, 700, 1280, 720)
    assert Box(1300, 10, 1400, 20).clip(1280, 720) is None
    assert Box(10, -30, 20, -1).clip(1280, 720) is None


# --------------------------------------------------------------------------- round trips


def test_labels_round_trip_and_first_csv_field(tmp_path):
    labels = ["mug", "red bottle", "keyboard"]
    write_labels(tmp_path / "labels.csv", labels)
    assert (tmp_path / "labels.csv").read_text() == "mug\nred bottle\nkeyboard\n"
    assert read_labels(tmp_path / "labels.csv") == labels
    p = write(tmp_path / "l2.csv", "mug,12\n\n# comment\nred bottle , x\nkeyboard\n")
    assert read_labels(p) == labels
    with pytest.raises(ValueError):
        write_labels(tmp_path / "bad.csv", ["a,b"])


def test_centers_round_trip_exact(tmp_path):
    centers = sample_annotations().centers
    p = tmp_path / "3d_center_annot.txt"
    write_centers(p, centers)
    assert read_centers(p) == centers
    first = p.read_text().splitlines()[0]
    assert first == f"{T0} {T0 + 5_000_000} 0 0.1234567891 -1.5 2 0"


def test_centers_separators_are_equivalent(tmp_path):
    rows = [f"{T0} {T0 + 10} 1 0.5 -1.25 2 0", f"{T0 + 11} {T0 + 20} 1 1.5 0 2 1"]
    ws = write(tmp_path / "ws.txt", "\n".join(rows) + "\n")
    comma = write(tmp_path / "comma.txt", "\n".join(r.replace(" ", ",") for r in rows) + "\n")
    mixed = write(tmp_path / "mixed.txt", "\n".join(r.replace(" ", " , ", 2).replace(" ", "\t", 1) for r in rows))
    expected = read_centers(ws)
    assert len(expected) == 2 and expected[1].location_id == 1
    assert read_centers(comma) == expected
    assert read_centers(mixed) == expected


def test_motion_round_trip_sorted_numerically(tmp_path):
    p = write(tmp_path / "m.txt", "1 100 200\n1 99 99\n0, 5, 10\n")
    got = read_motion_states(p)
    assert got == [MotionInterval(0, 5, 10), MotionInterval(1, 99, 99), MotionInterval(1, 100, 200)]
    out = tmp_path / "out.txt"
    write_motion_states(out, got)
    assert out.read_text() == "0 5 10\n1 99 99\n1 100 200\n"
    assert read_motion_states(out) == got


def test_bbox_annot_sorted_numerically_not_lexically(tmp_path):
    p = write(tmp_path / "0.txt", "100 0 0 1 1\n99 0 0 2 2\n1000 0 0 3 3\n")
    assert [ts for ts, _ in read_bbox_annot(p)] == [99, 100, 1000]
    p2 = write(tmp_path / "1.txt", f"{T0 * 10} 0 0 1 1\n{T0} 0 0 1 1\n")  # 19 vs 18 digits
    assert [ts for ts, _ in read_bbox_annot(p2)] == [T0, T0 * 10]


def test_bbox_annot_xywh_vs_xyxy(tmp_path):
    p = write(tmp_path / "0.txt", f"{T0} 10 20 30 40\n")
    assert read_bbox_annot(p) == [(T0, Box(10, 20, 30, 40))]
    assert read_bbox_annot(p, box_format="xywh") == [(T0, Box(10, 20, 40, 60))]
    out = tmp_path / "out.txt"
    write_bbox_annot(out, [(T0, Box(10, 20, 40, 60))], box_format="xywh")
    assert out.read_text() == f"{T0} 10 20 30 40\n"
    assert read_bbox_annot(out, box_format="xywh") == [(T0, Box(10, 20, 40, 60))]
    with pytest.raises(ValueError):
        read_bbox_annot(p, box_format="cxcywh")


def test_bbox_annot_dir_round_trip_and_numeric_ids(tmp_path):
    boxes = {10: [(T0, Box(1, 2, 3, 4))], 2: [(T0 + 1, Box(0.1234567891, 2, 3, 4))]}
    d = tmp_path / "2d_bbox_annot"
    write_bbox_annot_dir(d, boxes)
    got = read_bbox_annot_dir(d)
    assert list(got) == [2, 10]
    assert got == boxes
    # Rewriting replaces the folder: instances no longer present disappear.
    write_bbox_annot_dir(d, {2: boxes[2]})
    assert sorted(p.name for p in d.iterdir()) == ["2.txt"]


def test_bbox_annot_dir_bad_file_name(tmp_path):
    d = tmp_path / "2d_bbox_annot"
    write(d / "0.txt", "1 0 0 1 1\n")
    write(d / "mug.txt", "1 0 0 1 1\n")
    write(d / ".DS_Store", "junk")  # hidden files are ignored
    with pytest.raises(InputError) as err:
        read_bbox_annot_dir(d)
    assert_error_at(err, d / "mug.txt", None)


def test_svoe_round_trip_both_box_formats(tmp_path):
    svoe = sample_annotations().svoe
    for fmt in ("xyxy", "xywh"):
        p = tmp_path / f"svoe_{fmt}.txt"
        write_svoe(p, svoe, box_format=fmt)
        assert read_svoe(p, box_format=fmt) == svoe
    assert (tmp_path / "svoe_xywh.txt").read_text().splitlines()[1] == f"2 {T0 + 3} 5 6 2 2"


def test_mvpe_photos_sorted(tmp_path):
    for name in ("mug", "bottle"):
        for i in (10, 2, 1):
            write(tmp_path / "mvpe" / name / f"{i}.jpg", "")
    write(tmp_path / "mvpe" / "mug" / "notes.txt", "")
    got = read_mvpe_photos(tmp_path / "mvpe")
    assert list(got) == ["bottle", "mug"]
    assert [p.name for p in got["mug"]] == ["1.jpg", "2.jpg", "10.jpg"]
    with pytest.raises(InputError):
        read_mvpe_photos(tmp_path / "missing")


def test_save_and_load_annotations_round_trip(tmp_path):
    ann = sample_annotations()
    for fmt in ("xyxy", "xywh"):
        d = tmp_path / fmt
        save_annotations(d, ann, box_format=fmt)
        assert load_annotations(d, box_format=fmt) == ann


def test_load_annotations_optional_files_and_required_labels(tmp_path):
    d = tmp_path / "ann"
    write(d / "labels.csv", "mug\n")
    assert load_annotations(d) == Annotations(labels=["mug"])
    (d / "labels.csv").unlink()
    with pytest.raises(InputError) as err:
        load_annotations(d)
    assert err.value.path == d and "labels.csv" in str(err.value)


def test_load_annotations_instance_out_of_range(tmp_path):
    d = tmp_path / "ann"
    write(d / "labels.csv", "mug\nbottle\n")
    write(d / "motion_state_annot.txt", "0 1 2\n\n1 1 2\n2 1 2\n")
    with pytest.raises(InputError) as err:
        load_annotations(d)
    assert_error_at(err, d / "motion_state_annot.txt", 4)
    (d / "motion_state_annot.txt").unlink()
    write(d / "2d_bbox_annot" / "5.txt", "1 0 0 1 1\n")
    with pytest.raises(InputError) as err:
        load_annotations(d)
    assert_error_at(err, d / "2d_bbox_annot" / "5.txt", None)


# --------------------------------------------------------------------------- malformed input


@pytest.mark.parametrize(
    ("reader", "text", "line", "fragment"),
    [
        (read_centers, "# c\n1 2 0 0 0 0 0\n\n1 2 0 0 0 0\n", 4, "expected 7 columns"),
        (read_centers, "1 2 0 0 0 0 0\n1 2 zero 0 0 0 0\n", 2, "instance_id"),
        (read_centers, "1 2 0 0 nan 0 0\n", 1, "y"),
        (read_centers, "5 2 0 0 0 0 0\n", 1, "t_end"),
        (read_centers, "1 2 -1 0 0 0 0\n", 1, "negative"),
        (read_motion_states, "0 1 2\n0,1\n", 2, "expected 3 columns"),
        (read_bbox_annot, "1 0 0 1 1\n2 0 0 1 1\n\n3 10 0 5 1\n", 4, "x_max"),
        (read_bbox_annot, "1 0 0 1 inf\n", 1, "y_max"),
        (read_bbox_annot, "1.5 0 0 1 1\n", 1, "ts"),
        (read_svoe, "0 1 0 0 1 1\n0 1 0 2 1 1\n", 2, "y_max"),
        (read_svoe, "0 1 0 0 1 1 7\n", 1, "expected 6 columns"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, reader, text, line, fragment):
    p = write(tmp_path / "bad_file.txt", text)
    with pytest.raises(InputError) as err:
        reader(p)
    assert_error_at(err, p, line)
    assert fragment in err.value.message


def test_box_format_decides_validity(tmp_path):
    p = write(tmp_path / "0.txt", "1 10 10 20 3\n")
    assert read_bbox_annot(p, box_format="xywh") == [(1, Box(10, 10, 30, 13))]
    with pytest.raises(InputError) as err:
        read_bbox_annot(p)  # as xyxy, y_max 3 < y_min 10
    assert_error_at(err, p, 1)
    neg = write(tmp_path / "1.txt", "\n1 10 10 -5 3\n")
    with pytest.raises(InputError) as err:
        read_bbox_annot(neg, box_format="xywh")
    assert_error_at(err, neg, 2)


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError) as err:
        read_centers(tmp_path / "nope.txt")
    assert_error_at(err, tmp_path / "nope.txt", None)


class Exploding:
    """A record whose fields fail while being formatted."""

    instance = 0

    @property
    def t_start(self):
        raise RuntimeError("boom")


def test_failed_write_keeps_existing_file(tmp_path):
    p = tmp_path / "3d_center_annot.txt"
    good = sample_annotations().centers
    write_centers(p, good)
    before = p.read_text()
    with pytest.raises(RuntimeError, match="boom"):
        write_centers(p, [good[0], Exploding()])
    with pytest.raises(TypeError):
        write_bbox_annot(tmp_path / "b.txt", [(1.5, Box(0, 0, 1, 1))])  # float timestamp refused
    assert p.read_text() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["3d_center_annot.txt"]  # no temp files left


def test_failed_save_annotations_leaves_folder_untouched(tmp_path):
    d = tmp_path / "ann"
    save_annotations(d, sample_annotations())
    snapshot = {p.relative_to(d): p.read_bytes() for p in d.rglob("*") if p.is_file()}
    bad = sample_annotations()
    bad.svoe.append(SvoeEnrollment(7, T0, Box(0, 0, 1, 1)))  # id 7 has no label
    with pytest.raises(ValueError):
        save_annotations(d, bad)
    assert {p.relative_to(d): p.read_bytes() for p in d.rglob("*") if p.is_file()} == snapshot
