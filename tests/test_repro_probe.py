"""tools/repro_probe.py and the CPU identity in every benchmark record: the digests that locate
where two machines' figures part must see a last-bit change, ignore what is not content, and the
comparison must name the first stage that differs."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

import benchdoc  # noqa: E402
import repro_probe  # noqa: E402
from egograph.geometry.observations import Observations  # noqa: E402


def test_digest_sees_a_last_bit_and_ignores_key_order():
    x = np.linspace(0.0, 1.0, 101)
    y = x.copy()
    y[37] = np.nextafter(y[37], 2.0)   # one value moved by one unit in the last place
    assert repro_probe.digest({"a": x, "b": [1, 2.5]}) == repro_probe.digest({"b": [1, 2.5], "a": x.copy()})
    assert repro_probe.digest({"a": x}) != repro_probe.digest({"a": y})
    assert repro_probe.digest(0.1 + 0.2) != repro_probe.digest(0.3)
    # the same values in another dtype or shape are other content
    assert repro_probe.digest(x.astype(np.float32)) != repro_probe.digest(x)
    assert repro_probe.digest(x[:100].reshape(10, 10)) != repro_probe.digest(x[:100])


def test_digest_of_observations_ignores_provenance_only():
    m = 4
    obs = Observations(timestamps=np.arange(m, dtype=np.int64), frame=np.arange(m, dtype=np.int32),
                       instance=np.zeros(m, np.int32), score=np.ones(m, np.float32), box=np.zeros((m, 4), np.float32),
                       world=np.ones((m, 3)), camera=np.zeros((m, 3)), range_m=np.ones(m, np.float32),
                       candidates=np.full((m, 2, 3), np.nan), chosen=np.zeros(m, np.int8),
                       n_pixels=np.full(m, 9, np.int32), provenance={"recording": "/somewhere/else"})
    moved = dataclasses.replace(obs, world=obs.world + np.array([0.0, 0.0, 1e-12]))
    elsewhere = dataclasses.replace(obs, provenance={"recording": "/another/path"})
    assert repro_probe.digest(obs) == repro_probe.digest(elsewhere)
    assert repro_probe.digest(obs) != repro_probe.digest(moved)


def test_digest_refuses_what_it_cannot_read_by_content():
    with pytest.raises(TypeError, match="object"):
        repro_probe.digest({"x": object()})   # its repr would carry a memory address


def test_files_digest_names_and_bytes(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "a.png").write_bytes(b"\x00\x01")
    (tmp_path / "d" / "b.png").write_bytes(b"\x02")
    first = repro_probe.files_digest(tmp_path, ["d/*"])
    assert first[1] == 2
    (tmp_path / "d" / "b.png").write_bytes(b"\x03")
    assert repro_probe.files_digest(tmp_path, ["d/*"])[0] != first[0]
    assert repro_probe.files_digest(tmp_path, ["none/*"])[1] == 0


def test_compare_names_the_first_stage_that_differs():
    mine = {"libraries": {"blas": "1", "embree": "2"},
            "recordings": {"seed1": {"generate/poses": "a", "lift/svoe/robust": "b", "track/svoe/graph": "c"},
                           "seed2": {"generate/poses": "a", "lift/svoe/robust": "b"},
                           "seed3": {"generate/poses": "a"}}}
    theirs = {"libraries": {"blas": "9", "embree": "2"},
              "recordings": {"seed1": {"generate/poses": "a", "lift/svoe/robust": "X", "track/svoe/graph": "Y"},
                             "seed2": {"generate/poses": "a", "lift/svoe/robust": "b"}}}
    lines = repro_probe.compare(mine, theirs)
    assert lines[0] == "library probes: 1 of 2 differ: blas"
    assert lines[1] == "seed1: first differs at lift/svoe/robust; 2 of 3 stages differ (lift/svoe/robust, track/svoe/graph)"
    assert lines[2] == "seed2: all 2 stages the same"
    assert lines[3] == "seed3: not in the other record"


CPUINFO = """processor\t: 0
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 143
model name\t: Intel(R) Xeon(R) Processor
stepping\t: 8
flags\t\t: fpu sse4_2 avx avx2 fma avx512f avx512bw avx512_fp16 amx_tile

processor\t: 1
vendor_id\t: AuthenticAMD
model name\t: not the first block
"""


def test_cpu_identity_reads_the_first_processor_block():
    ident = benchdoc.cpu_identity(CPUINFO)
    assert ident == {"cpu": "Intel(R) Xeon(R) Processor", "vendor": "GenuineIntel", "family": 6, "model": 143,
                     "stepping": 8, "isa": ["sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512_fp16",
                                            "amx_tile"]}
    assert benchdoc.cpu_identity("") == {}


def test_every_record_names_the_cpu_and_the_blas_kernels(monkeypatch):
    np.linalg.solve(np.eye(3), np.ones(3))   # OpenBLAS loaded and initialised
    monkeypatch.setenv("OPENBLAS_L2_SIZE", "512")
    doc = benchdoc.Bench("bench_x", {}, argv=["--seeds", "1"], path="-").document()
    m = doc["machine"]
    # a variable that chooses kernels is kept beside the CPU, not in the command a reader copies
    assert m["kernel_environment"]["OPENBLAS_L2_SIZE"] == "512"
    assert doc["command"] == "tools/bench_x.py --seeds 1" and "OPENBLAS_L2_SIZE" not in doc["environment"]
    if Path("/proc/cpuinfo").exists():
        assert m["cpu_id"]["vendor"] and isinstance(m["cpu_id"]["isa"], list)
    blas = [lib for lib in m["math_libraries"] if lib.get("internal_api") == "openblas"]
    assert blas and all(lib.get("architecture") for lib in blas)   # e.g. Haswell, SkylakeX


def test_frontend_probe_repeats_itself_and_covers_every_proposal_source(device_rec):
    first = repro_probe.frontend_digests(device_rec, step=50)
    again = repro_probe.frontend_digests(device_rec, step=50)
    assert first == again   # one machine repeats itself: what makes a difference between two mean something
    assert [k for k in first if k.startswith("generate/")][-1] == "generate/pv"
    assert first["generate/pv"].endswith("(150 files)")
    # every source of SVOE's default proposals is digested on its own, then the chain after them
    assert {"proposals/geometry", "proposals/mesh", "proposals/image"} <= set(first)
    assert list(first)[-3:] == ["proposals/plausible", "proposals/rank", "proposals/kept at the cap"]
    assert repro_probe.compare({"recordings": {"r": first}}, {"recordings": {"r": again}})[1] == \
        f"r: all {len(first)} stages the same"
