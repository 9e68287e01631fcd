"""Which calibration folder a sequence is read with: the one its number names, unless another
candidate fits the sequence's own frames clearly better (:mod:`egograph.geometry.calib_fit`).

The IT3DEgo release ships one calibration folder per group of recordings (``calibrations_vid1_17``
...); users report that the group's own folder does not fit some sequences. With several candidate
folders (and ``calib_fit.select``), every candidate is scored on the same sampled frames; when the
number-chosen one fits clearly worse than the best (``calib_fit.margin_px`` and
``calib_fit.margin_sigmas``), the best is used and one warning names both folders and their
scores. ``--calibration DIR`` always wins. Under ``--strict`` a calibration whose fit test fails
(:meth:`~egograph.geometry.calib_fit.FitScore.fits`) is refused.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

from egograph.core.errors import InputError
from egograph.geometry.calib_fit import FitCandidate, FitSample, FitScore, compare, fit_score, prepare_fit
from egograph.io.calibration import calibration_choice, read_ahat_calibration, read_pv_calibration


@dataclass
class CalibrationFit:
    """The fit of every candidate folder on one sample of a recording: ``scores`` by folder,
    ``by_number`` (the folder the sequence's number names, or None), ``used`` (the folder read),
    ``explicit`` (given with --calibration), ``switched`` (the number-chosen folder was passed over),
    and why frames were left out of the sample."""

    scores: dict[Path, FitScore] = field(default_factory=dict)
    by_number: Path | None = None
    used: Path | None = None
    explicit: bool = False
    switched: bool = False
    frames: int = 0
    skipped: dict = field(default_factory=dict)
    note: str = ""

    def to_json(self, cfg) -> dict:
        return {"used": str(self.used) if self.used else None,
                "by_number": str(self.by_number) if self.by_number else None,
                "explicit": self.explicit, "switched": self.switched, "frames": self.frames,
                "skipped_frames": self.skipped, "note": self.note,
                "candidates": [{"folder": str(p), **s.to_json(), "fits": s.fits(cfg),
                                "used": p == self.used, "by_number": p == self.by_number}
                               for p, s in self.scores.items()]}


def candidate(folder: Path) -> FitCandidate:
    """The calibration in ``folder`` (holding rm_depth_ahat/ and personal_video/) as a fit candidate."""
    ahat = read_ahat_calibration(folder / "rm_depth_ahat")
    return FitCandidate.of(ahat, read_pv_calibration(folder / "personal_video"), folder.name)


def score_folders(rec, folders: list[Path], cfg, sample: FitSample | None = None) -> tuple[dict, FitSample]:
    """Every folder's fit on one sample of ``rec`` (drawn with ``cfg.calib_fit`` unless given). A folder
    that cannot be read is warned about (naming it) and left out."""
    fc = cfg.calib_fit
    sample = sample if sample is not None else prepare_fit(rec, fc)
    scores = {}
    for folder in folders:
        try:
            scores[folder] = fit_score(rec, sample, candidate(folder), fc)
        except InputError as err:
            warnings.warn(f"{err.path}: {err.message}; calibration folder {folder} not scored", stacklevel=2)
    return scores, sample


def _describe(folder: Path, s: FitScore) -> str:
    return f"{folder.name} {s.score:.2f} px (spread {s.spread:.2f})"


def choose_calibration(rec, cfg, explicit: bool, strict: bool, always_score: bool = False) -> tuple[Path, CalibrationFit]:
    """The folder ``rec`` should be read with, and the fit of every candidate. ``rec`` was opened
    with the folder named by number (or the first candidate when none is named) or with the explicit
    folder. Candidates are scored when there are several, under ``strict``, or with ``always_score``
    (``egograph info``); a recording without PV images cannot be scored (said in ``note``)."""
    fc = cfg.calib_fit
    fit = CalibrationFit(used=rec.calibration_dir, explicit=explicit)
    if explicit:
        folders = [rec.calibration_dir]
    else:
        choice = calibration_choice(rec.seq_dir)
        folders, fit.by_number = choice.candidates, choice.by_number
    several = len(folders) > 1 and fc.select and not explicit
    if not (several or strict or always_score):
        return rec.calibration_dir, fit
    sample = prepare_fit(rec, fc)
    fit.frames, fit.skipped = len(sample.frames), sample.skipped
    if len(sample.frames) < 2:
        fit.note = (f"not scored: {len(sample.frames)} usable frames of {len(rec)} (left out: "
                    + (", ".join(f"{n} {why}" for why, n in sample.skipped.items()) or "no frame with both poses")
                    + ")")
        if several and fit.by_number is None:
            names = ", ".join(p.name for p in folders)
            raise InputError(rec.seq_dir, f"{len(folders)} calibration folders ({names}) and none named for this "
                                          f"sequence's number; the fit cannot choose ({fit.note}); pass --calibration DIR")
        return rec.calibration_dir, fit
    fit.scores, _ = score_folders(rec, folders, cfg, sample)
    used = rec.calibration_dir
    if several and fit.scores:
        best = min(fit.scores, key=lambda p: fit.scores[p].score)
        named = fit.by_number
        if named is None:
            used = best
            warnings.warn(f"{rec.seq_dir}: no calibration folder is named for this sequence; using the best-fitting "
                          f"{_describe(best, fit.scores[best])} of " + ", ".join(
                              _describe(p, s) for p, s in fit.scores.items()), stacklevel=2)
        elif best != named and named in fit.scores and compare(fit.scores[best], fit.scores[named]).clearly_worse(fc):
            used, fit.switched = best, True
            warnings.warn(f"{rec.seq_dir}: calibration {_describe(named, fit.scores[named])} named for this sequence "
                          f"fits clearly worse than {_describe(best, fit.scores[best])} (mean distance of depth edges "
                          f"to PV edges, lower fits better); using {best} (--calibration DIR overrides, "
                          "calib_fit.select=false keeps the named one)", stacklevel=2)
    fit.used = used
    s = fit.scores.get(used)
    if strict and s is not None and not s.fits(fc):
        raise InputError(used, f"the calibration does not fit this sequence: shifting its depth edges by "
                               f"({s.offset_px[0]:g}, {s.offset_px[1]:g}) PV px lowers their distance to the PV edges "
                               f"by {s.offset_gain_px:.2f} px (score {s.score:.2f} px; calib_fit.max_offset_px "
                               f"{fc.max_offset_px:g}; --strict / io.strict); `egograph info --refine-calibration OUT` "
                               "fits a calibration to it")
    return used, fit


def refine_calibration_folder(rec, cfg, out: str | Path, frames: int = 200, overwrite: bool = False,
                              max_evaluations: int = 1500):
    """Fit the AHAT extrinsics and time offset of ``rec``'s calibration to its frames
    (:func:`egograph.geometry.calib_refine.refine_calibration` on ``frames`` sampled frames) and write
    the result as a calibration folder ``out`` in the release's format (``rm_depth_ahat/`` with
    ``time_offset.bin``, ``personal_video/`` as it was), with ``fit.json`` (the change, the scores
    before and after) and the run record, in one rename. ``out`` already holding this exact run is
    left as it is (returns None)."""
    import json

    from egograph.core.config import to_dict
    from egograph.geometry.calib_refine import refine_calibration
    from egograph.io.atomic import atomic_dir
    from egograph.io.calibration import write_ahat_calibration, write_pv_calibration
    from egograph.steps import outputs

    out = Path(out)
    if out.resolve() == Path(rec.calibration_dir).resolve():
        raise InputError(out, "the refined calibration would replace the one it starts from; choose another folder")
    record = outputs.run_record("refine-calibration", cfg, {"recording": outputs.recording_digest(rec),
                                                            "calibration": str(rec.calibration_dir),
                                                            "frames": frames, "max_evaluations": max_evaluations},
                                depends_on={"calib_fit": to_dict(cfg.calib_fit)})
    if outputs.up_to_date(out, record, overwrite):
        return None
    start = candidate(Path(rec.calibration_dir))
    result = refine_calibration(rec, start, cfg.calib_fit, frames=frames, max_evaluations=max_evaluations)
    if not result.before.per_frame.size:
        raise InputError(rec.seq_dir / "pv", "no frame with a PV image, an AHAT frame and both poses: nothing to fit")
    with atomic_dir(out) as tmp:
        write_ahat_calibration(tmp / "rm_depth_ahat", result.candidate.ahat)
        write_pv_calibration(tmp / "personal_video", result.candidate.pv)
        (tmp / "fit.json").write_text(json.dumps({"from": str(rec.calibration_dir), **result.to_json()}, indent=1))
        outputs.write_run_files(tmp, record, cfg)
    return result
