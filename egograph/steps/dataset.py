"""The sequences of a dataset: what ``egograph run DATASET`` processes.

A dataset is any folder :func:`egograph.io.recording.list_sequence_dirs` finds sequences in: a
sequence folder, a root holding sequences (``egograph synth`` writes one holding one sequence),
the IT3DEgo release's root (``raw_video_seqs/<seq>/`` beside ``annotations/``), or a folder of
``egograph synth`` outputs (``DATASET/<name>/<seq>/``).

Each sequence gets an id that names its outputs and its rows in the summary: the sequence
folder's name when those are unique, else the name of the folder holding it (a folder of synth
outputs whose recordings share a sequence name), else both joined with ``-``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from egograph.core.errors import InputError
from egograph.io.recording import list_sequence_dirs


@dataclass(frozen=True)
class DatasetSequence:
    id: str      # unique within the dataset; names the outputs and summary rows
    path: Path   # the sequence folder (holding pv_pose.json), absolute


def sequence_ids(dirs: list[Path]) -> list[str]:
    """Ids for sequence folders (see the module doc)."""
    names = [d.name for d in dirs]
    if len(set(names)) == len(names):
        return names
    parents = [d.parent.name for d in dirs]
    if len(set(parents)) == len(parents):
        return parents
    return [f"{d.parent.name}-{d.name}" for d in dirs]


def list_dataset(root: str | Path) -> list[DatasetSequence]:
    """Every sequence of the dataset at ``root``, sorted by id; InputError naming what was tried
    when there is none or two get the same id."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "dataset not found (expected a folder of sequences)")
    dirs = list_sequence_dirs(root)
    if not dirs:  # a folder of `egograph synth` outputs: DATASET/<name>/<seq>/
        dirs = [d for sub in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
                for d in list_sequence_dirs(sub)]
    dirs = sorted({d.resolve() for d in dirs})
    if not dirs:
        raise InputError(root, f"no sequence found (tried {root}/pv_pose.json, {root}/*/pv_pose.json, "
                               f"{root}/*/*/pv_pose.json)")
    ids = sequence_ids(dirs)
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise InputError(root, f"two sequences would share the id {dup[0]}; give them distinct folder names")
    return sorted((DatasetSequence(i, d) for i, d in zip(ids, dirs)), key=lambda s: s.id)
