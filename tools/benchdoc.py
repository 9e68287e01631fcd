"""Benchmarks as data: what every ``tools/bench_*.py`` prints is also written as one JSON file,
from which ``tools/bench_report.py`` renders ``docs/benchmarks.md``.

A tool records a table with one call, which prints it (Markdown, as the tools always printed)
and keeps it for the JSON file::

    import benchdoc                                    # tools/ is on sys.path when a tool runs

    ap = argparse.ArgumentParser(...)
    benchdoc.add_arguments(ap, __file__)               # --json PATH | -, --json-tag TAG
    args = ap.parse_args()
    benchdoc.start(__file__, args)                     # provenance, wall clock from here
    benchdoc.table("Graph solve time against length",
                   ["frames", "observations", "graph (s)"],
                   [[1000, 660, 0.27], [10000, 8875, 3.41]],
                   formats=["d", "d", ".2f"], note="best of 2 runs per size")
    benchdoc.text("growth 1000 -> 10000 frames: time x12.6")   # a sentence of figures
    benchdoc.finish()                                  # writes docs/bench/bench_graph_speed.json

Cells stay numbers in the JSON; ``formats`` (one per column) says how they print: a
``format()`` spec (``".2f"``, ``"d"``, ``""`` = ``str``), a ``str.format`` pattern with ``{}``
for a cell that is a list of numbers (``"{0}/{1} ({2:.0f} %)"`` with ``[42, 209, 20.1]``), or
``"yes|NO"`` for a boolean. ``None`` (and NaN, stored as null) prints ``n/a``. What is printed is
rendered from the JSON-normalised cells, so the tool's output and docs/benchmarks.md show the
same characters.

The JSON file (``FORMAT``): ``tool``, ``command`` (as typed, from the repository root),
``argv``, ``arguments`` (every parsed argument: seeds, frames, ...), ``environment`` (the
variables that change speed, e.g. ``LP_NUM_THREADS``), ``egograph`` (version, git ``commit``,
``dirty``: tracked files other than docs/ and README.md differ from the commit), ``packages`` (the installed versions of egograph's
dependencies and of Python: records made with other versions say so), ``machine`` (``nproc``, ``cpu_affinity``,
``cpu``, ``memory_gb``, ``load_average`` at the start and the end, ``cpu_id``: vendor, family, model
and instruction sets, ``kernel_environment``: the variables that choose kernels, ``math_libraries``: the
BLAS kernels chosen), ``started`` (UTC),
``wall_s``, ``items`` (tables and sentences in the order printed) and ``data`` (extra raw
records a tool keeps, not rendered).

Without ``start()`` (a tool's function called from elsewhere) ``table`` and ``text`` only print.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

FORMAT = "egograph-bench/1"
REPO = Path(__file__).resolve().parents[1]
BENCH_DIR = REPO / "docs" / "bench"
# Environment variables recorded with a run because they change what it measures.
ENV_KEYS = ("LP_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "EGOGRAPH_CACHE")
KERNEL_ENV_PREFIXES = ("OPENBLAS_", "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES", "OPENCV_", "MKL_CBWR")
"""Environment variables that choose which kernels compute a figure rather than how fast (OpenBLAS's
core type and cache sizes, numpy's and OpenCV's dispatch, MKL's reproducibility mode): kept in the
record's ``machine`` block beside the CPU's identity, not in its command line (some machines set
OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE for every process)."""
NA = "n/a"

_current: "Bench | None" = None


# --------------------------------------------------------------------------- cells and tables


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON data: numpy scalars and arrays to Python numbers and lists,
    NaN and infinities to None, paths and other objects to strings, tuples to lists."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):  # numpy scalar or array
        return jsonable(value.tolist())
    if isinstance(value, Path):
        return str(value)
    return str(value)


def dumps(value: Any, level: int = 0) -> str:
    """JSON text, indented by one space per level, with each list that holds no dict and not only
    lists on one line (a table row, the columns), so a table reads row by row."""
    pad, inner = " " * level, " " * (level + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        parts = [f"{inner}{json.dumps(str(k), ensure_ascii=False)}: {dumps(v, level + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(parts) + "\n" + pad + "}"
    if isinstance(value, list):
        if not any(isinstance(v, dict) for v in value) and not (value and all(isinstance(v, list) for v in value)):
            return json.dumps(value, ensure_ascii=False, allow_nan=False)
        return "[\n" + ",\n".join(inner + dumps(v, level + 1) for v in value) + "\n" + pad + "]"
    return json.dumps(value, ensure_ascii=False, allow_nan=False)


def _relative(value: Any) -> Any:
    """Paths inside the checkout as relative paths (the same run from another clone records the same)."""
    if isinstance(value, dict):
        return {k: _relative(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_relative(v) for v in value]
    if isinstance(value, str) and value.startswith(str(REPO) + os.sep):
        return value[len(str(REPO)) + 1:]
    return value


def format_cell(value: Any, fmt: str | None) -> str:
    """One cell as printed (see the module doc for ``fmt``)."""
    if value is None:
        return NA
    if isinstance(value, str):  # a word or mark ("-" = does not apply) prints as it is, whatever the format
        return value
    fmt = fmt or ""
    if isinstance(value, bool) and "|" in fmt:
        yes, _, no = fmt.partition("|")
        return yes if value else no
    if "{" in fmt:
        if isinstance(value, list):
            if any(v is None for v in value):
                return NA
            return fmt.format(*value)
        return fmt.format(value)
    if isinstance(value, list):
        return " / ".join(format_cell(v, fmt) for v in value)
    if not fmt:
        return str(value)
    return format(value, fmt)


def _md(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def table_lines(item: dict) -> list[str]:
    """The Markdown lines of a recorded table (header, rule, rows): what the tool printed and
    what docs/benchmarks.md shows."""
    cols = item["columns"]
    fmts = item.get("formats") or [""] * len(cols)
    lines = ["| " + " | ".join(_md(c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for row in item["rows"]:
        lines.append("| " + " | ".join(_md(format_cell(v, f)) for v, f in zip(row, fmts)) + " |")
    return lines


def item_lines(item: dict, heading: str = "###") -> list[str]:
    """A recorded item as Markdown: a table with its title and note, or a sentence."""
    if item["type"] == "text":
        return [item["text"]]
    out = [f"{heading} {item['title']}" if heading else item["title"], "", *table_lines(item)]
    if item.get("note"):
        out += ["", item["note"]]
    return out


def make_table(title: str, columns: Sequence[str], rows: Sequence[Sequence[Any]],
               formats: Sequence[str | None] | None = None, note: str | None = None) -> dict:
    """A table item, checked (one format per column, every row as wide as the header) and
    JSON-normalised."""
    columns = [str(c) for c in columns]
    if formats is not None and len(formats) != len(columns):
        raise ValueError(f"table {title!r}: {len(formats)} formats for {len(columns)} columns")
    rows = [list(r) for r in rows]
    for r in rows:
        if len(r) != len(columns):
            raise ValueError(f"table {title!r}: a row of {len(r)} cells for {len(columns)} columns: {r}")
    item = {"type": "table", "title": str(title), "columns": columns,
            "formats": [f or "" for f in formats] if formats is not None else [""] * len(columns),
            "rows": jsonable(rows)}
    if note:
        item["note"] = str(note)
    return item


# --------------------------------------------------------------------------- provenance


def _git(*args: str) -> str | None:
    try:
        p = subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def revision() -> dict:
    """egograph's version and the checkout's git commit; ``dirty`` when tracked files outside docs/
    and README.md differ from it."""
    try:
        from egograph import __version__ as version
    except ImportError:  # pragma: no cover - tools always run with egograph installed
        version = None
    commit = _git("rev-parse", "HEAD")
    # docs/ (where the figures go) and README.md (whose score block tools/bench_report.py rewrites after
    # each README record, while a regeneration runs) do not change what is measured
    status = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)docs",
                  ":(exclude)README.md") if commit else None
    return {"version": version, "commit": commit, "dirty": bool(status) if commit else None}


ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "fma4", "avx512f", "avx512dq", "avx512cd", "avx512bw", "avx512vl",
             "avx512ifma", "avx512vbmi", "avx512_vbmi2", "avx512_vnni", "avx512_bitalg", "avx512_vpopcntdq",
             "avx512_bf16", "avx512_fp16", "avx512_vp2intersect", "avx_vnni", "amx_tile", "amx_bf16")
"""The instruction-set flags a record names (of /proc/cpuinfo's): the libraries egograph calls pick
their kernels by them (numpy's loops, OpenBLAS, OpenCV, Open3D's Embree and ISPC, onnxruntime's MLAS),
and the benchmark figures have been seen to differ between CPUs (docs/experiments.md, stops 65-66)."""


def cpu_identity(cpuinfo: str | None = None) -> dict:
    """The CPU's model name, vendor, family, model and stepping, and which of :data:`ISA_FLAGS` it
    has, from the first processor's block of ``cpuinfo`` (default: Linux's /proc/cpuinfo; {} where
    there is none)."""
    keys = {"model name": "cpu", "vendor_id": "vendor", "cpu family": "family", "model": "model",
            "stepping": "stepping", "flags": "flags"}
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return {}
    out: dict = {}
    for line in cpuinfo.splitlines():
        if not line.strip() and out:   # the first processor's block is enough
            break
        name, _, value = line.partition(":")
        key = keys.get(name.strip())
        if key and key not in out:
            out[key] = value.strip()
    if not out:
        return {}
    flags = set(out.pop("flags", "").split())
    for key in ("family", "model", "stepping"):
        if str(out.get(key, "")).isdigit():
            out[key] = int(out[key])
    out["isa"] = [f for f in ISA_FLAGS if f in flags]
    return out


def math_libraries() -> list[dict]:
    """The BLAS and OpenMP libraries loaded in this process with the kernels they chose
    (threadpoolctl: OpenBLAS's ``architecture``, e.g. Haswell or SkylakeX) and their threads."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return []
    keep = ("internal_api", "version", "architecture", "num_threads", "filepath")
    return [{k: (Path(v).name if k == "filepath" else v) for k, v in info.items() if k in keep and v is not None}
            for info in threadpool_info()]


def machine() -> dict:
    """nproc, the CPUs this process may run on, CPU model, memory (GB), load average now, and the
    CPU's identity and instruction sets (:func:`cpu_identity`)."""
    ident = cpu_identity()
    cpu = ident.pop("cpu", None)
    mem = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem = round(int(line.split()[1]) / 1024 ** 2, 1)
                break
    except OSError:
        pass
    try:
        affinity = sorted(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        affinity = None
    kernel_env = {k: v for k, v in sorted(os.environ.items()) if k.startswith(KERNEL_ENV_PREFIXES)
                  and k not in ENV_KEYS}
    return {"nproc": os.cpu_count(), "cpu_affinity": affinity, "cpu": cpu, "memory_gb": mem,
            "load_average": [round(x, 2) for x in os.getloadavg()], "cpu_id": ident, "kernel_environment": kernel_env}


def tool_name(file: str | Path) -> str:
    return Path(file).stem


def default_path(tool: str, tag: str | None = None) -> Path:
    """``docs/bench/<tool>[-<tag>].json`` in the checkout the tool belongs to."""
    return BENCH_DIR / (f"{tool}-{tag}.json" if tag else f"{tool}.json")


def add_arguments(ap: argparse.ArgumentParser, file: str | Path) -> None:
    """``--json PATH`` and ``--json-tag TAG``: where the run's figures go."""
    tool = tool_name(file)
    g = ap.add_argument_group("figures as data (tools/benchdoc.py; docs/benchmarks.md renders them)")
    g.add_argument("--json", metavar="PATH", help=f"write every printed table and the run's provenance here "
                   f"(default: docs/bench/{tool}.json, or docs/bench/{tool}-TAG.json with --json-tag; "
                   "'-' writes no file)")
    g.add_argument("--json-tag", metavar="TAG", help="a variant's name in the default path, for runs of "
                   "this tool with other settings kept side by side")


# --------------------------------------------------------------------------- a run


class Bench:
    """One benchmark run: provenance, the wall clock, every recorded item."""

    def __init__(self, tool: str, args: argparse.Namespace | dict | None = None,
                 argv: Sequence[str] | None = None, path: str | Path | None = None):
        self.tool = tool
        self.argv = list(sys.argv[1:] if argv is None else argv)
        params = vars(args) if isinstance(args, argparse.Namespace) else dict(args or {})
        tag = params.get("json_tag")
        target = params.get("json") if path is None else path
        self.path: Path | None = None if target == "-" else Path(target) if target else default_path(tool, tag)
        self.arguments = _relative(jsonable({k: v for k, v in params.items() if k not in ("json", "json_tag")}))
        self.items: list[dict] = []
        self.data: dict = {}
        self.started = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
        self.machine = machine()
        self.revision = revision()
        self.environment = {k: os.environ[k] for k in ENV_KEYS if k in os.environ}
        self.packages = packages()
        self._t0 = time.perf_counter()

    def table(self, *a, **kw) -> dict:
        item = make_table(*a, **kw)
        self.items.append(item)
        return item

    def text(self, text: str) -> dict:
        item = {"type": "text", "text": str(text).strip("\n")}
        self.items.append(item)
        return item

    def document(self) -> dict:
        m = dict(self.machine)
        m["load_average"] = {"start": m["load_average"], "end": [round(x, 2) for x in os.getloadavg()]}
        m["math_libraries"] = math_libraries()   # at the end: the libraries the run loaded
        return {
            "format": FORMAT,
            "tool": self.tool,
            "command": shlex.join([f"tools/{self.tool}.py", *self.argv]),
            "argv": self.argv,
            "arguments": self.arguments,
            "environment": self.environment,
            "egograph": self.revision,
            "packages": self.packages,
            "machine": m,
            "started": self.started,
            "wall_s": round(time.perf_counter() - self._t0, 1),
            "items": self.items,
            "data": jsonable(self.data),
        }

    def write(self) -> Path | None:
        """Write the JSON file (atomically; nothing when the path is ``-``) and return its path."""
        if self.path is None:
            return None
        from egograph.io.atomic import atomic_write_text

        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.path, dumps(self.document()) + "\n")
        return self.path


def packages() -> dict[str, str]:
    """``{distribution: version}`` of everything egograph requires (its extras included) as
    installed, and ``python``: what a figure was measured with (stop 51: a rebuilt environment with
    unpinned dependencies moved baselines by up to 0.7 points, and the records could not say why)."""
    import platform
    import re
    from importlib import metadata

    out = {"python": platform.python_version()}
    try:
        requires = metadata.requires("egograph") or []
    except metadata.PackageNotFoundError:
        requires = []
    for req in requires:
        name = re.split(r"[ ;<>=!~\[(]", req, maxsplit=1)[0]
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:  # another platform's alternative, or an extra not installed
            continue
    return dict(sorted(out.items()))


def start(file: str | Path, args: argparse.Namespace | dict | None = None, argv: Sequence[str] | None = None) -> Bench:
    """Begin recording this run of the tool ``file`` (its ``__file__``) with its parsed ``args``."""
    global _current
    _current = Bench(tool_name(file), args, argv)
    return _current


def current() -> Bench | None:
    return _current


def table(title: str, columns: Sequence[str], rows: Sequence[Sequence[Any]],
          formats: Sequence[str | None] | None = None, note: str | None = None) -> dict:
    """Print a table (its title, the Markdown table, the note) and record it in the current run."""
    item = _current.table(title, columns, rows, formats, note) if _current else make_table(title, columns, rows,
                                                                                          formats, note)
    print("\n".join(item_lines(item)) + "\n", flush=True)
    return item


def text(line: str) -> dict:
    """Print a sentence of figures (a verdict, a ratio) as given and record it in the current run
    (without leading and trailing blank lines)."""
    item = _current.text(line) if _current else {"type": "text", "text": str(line).strip("\n")}
    print(line, flush=True)
    return item


def finish() -> Path | None:
    """Write the current run's JSON file and say where (stderr); the path, or None."""
    global _current
    if _current is None:
        return None
    path = _current.write()
    _current = None
    if path is not None:
        print(f"figures written to {path}", file=sys.stderr, flush=True)
    return path
