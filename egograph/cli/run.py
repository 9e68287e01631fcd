"""``egograph run``: every stage on every sequence of a dataset, on a Dask cluster.

    egograph run DATASET --out RUNS [--stages [detect,]lift,track,eval] [--trackers graph,memory]
                 [--detections svoe|mvpe] [--workers N | --scheduler ADDRESS] [--name NAME]

Exit code 0 when every task succeeded, 1 when some failed (each reported with its one-line error,
the others carried on), 2 when none succeeded or the input is unusable (nothing written then).
"""

from __future__ import annotations

from pathlib import Path


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_parser(sub, add_config_args, default_config: Path) -> None:
    """Add the ``run`` sub-command."""
    from egograph.steps.run import DEFAULT_STAGES, PLANNED_STAGES, STAGES
    from egograph.track.registry import TRACKERS

    s = sub.add_parser("run", help="every stage on every sequence of a dataset, on a Dask cluster (resumable)")
    s.add_argument("dataset", type=Path,
                   help="dataset: a root holding sequences (the IT3DEgo release: raw_video_seqs/ and annotations/) "
                        "or a folder whose sub-folders are `egograph synth` outputs")
    s.add_argument("--out", required=True, type=Path,
                   help="runs folder: RUNS/cache/<seq>/ (step outputs, reused by later runs), RUNS/<name>/ "
                        "(config.yaml, run.json, summary.json, links per sequence), RUNS/latest")
    s.add_argument("--stages", type=_csv, default=list(DEFAULT_STAGES), metavar="LIST",
                   help=f"comma-separated, from {','.join(STAGES)} (default {','.join(DEFAULT_STAGES)}); a stage "
                        "brings the ones it needs (eval: track, lift); refine's poses feed the later stages; detect "
                        "runs `egograph detect` (enrollment --detections, front-end config frontend.*) on each "
                        "sequence's PV frames and lift reads its detections instead of the recording's; adapt "
                        "(with detect and the graph tracker) iterates adapt.rounds rounds of detect -> lift -> "
                        "track -> eval, each round's front-end taught by the graph's results of the round before "
                        "(docs/frontend-adapt.md)"
                        + "".join(f"; {k}: {v}" for k, v in PLANNED_STAGES.items()))
    s.add_argument("--trackers", type=_csv, default=list(TRACKERS), metavar="LIST",
                   help=f"comma-separated, from {','.join(TRACKERS)} (default all)")
    s.add_argument("--detections", default="svoe",
                   help="detection set of every sequence (svoe, mvpe; default svoe): the recording's own set of "
                        "that name, or with --stages detect the enrollment detect uses (svoe: the box of "
                        "svoe.txt; mvpe: the instance photos)")
    s.add_argument("--workers", type=int, default=2,
                   help="worker processes of the local Dask cluster (one thread each; default 2); it listens on "
                        "127.0.0.1 only and opens no dashboard")
    s.add_argument("--scheduler", metavar="ADDRESS",
                   help="use a running Dask cluster instead (tcp://HOST:8786, or tls://... with the TLS settings of "
                        "Dask's configuration); its workers must see DATASET and RUNS at the same paths")
    s.add_argument("--name", help="run name (default: <dataset>-<digest of dataset, stages, trackers, config>, so "
                                  "the same command resumes the same run)")
    s.add_argument("--lift", choices=["reference", "robust"], help="lifting mode (default from config lift.mode)")
    s.add_argument("--strict", action="store_true", help="refuse partly unusable input (sets io.strict)")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_args(s, default_config)
    s.set_defaults(func=cmd_run)


def cmd_run(args) -> int:
    from egograph.cli.common import _console, pipeline_config
    from egograph.steps.run import open_client, plan_run, run_dataset

    cfg = pipeline_config(args)
    plan = plan_run(args.dataset, args.out, cfg, stages=args.stages, trackers=args.trackers,
                    detections=args.detections, name=args.name)
    con = _console()
    client = open_client(args.workers, args.scheduler)  # before anything is written: an unreachable scheduler fails here
    where = args.scheduler or f"a local cluster of {args.workers} worker(s)"
    con.print(f"run {plan.name}: {len(plan.sequences)} sequence(s), {len(plan.tasks)} tasks "
              f"({', '.join(plan.stages)}; trackers {', '.join(plan.trackers) or '-'}) on {where}")
    try:
        if args.quiet:
            outcome = run_dataset(plan, cfg, client=client, progress=_print_failure(con))
        else:
            outcome = _with_progress(con, plan, cfg, client)
    finally:
        from egograph.steps.run import close_client

        close_client(client)
    return _report(con, outcome)


def _print_failure(con):
    def show(task, res):
        if res["status"] == "failed":
            con.print(f"[red]{task.key} failed:[/red] {res['error']}", soft_wrap=True)
    return show


def _with_progress(con, plan, cfg, client):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from egograph.steps.run import run_dataset

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=con, transient=True) as bar:
        job = bar.add_task("tasks", total=len(plan.tasks))
        show = _print_failure(bar.console)

        def progress(task, res):
            show(task, res)
            bar.update(job, advance=1, description=f"{task.key} {res['status']}")

        return run_dataset(plan, cfg, client=client, progress=progress)


def _report(con, outcome) -> int:
    from rich.table import Table

    from egograph.eval.report import EvalReport, print_comparison
    from egograph.steps.run import OK

    plan, results, summary = outcome.plan, outcome.results, outcome.summary
    t = Table(title="tasks per sequence (ok / all)")
    t.add_column("sequence", overflow="fold")
    for stage in plan.stages:
        t.add_column(stage, justify="right")
    for seq in plan.sequences:
        row = [seq.id]
        for stage in plan.stages:
            mine = [results[task.key] for task in plan.tasks if task.sequence == seq.id and task.stage == stage]
            n_ok = sum(r["status"] == OK for r in mine)
            row.append(f"{n_ok}/{len(mine)}" if n_ok == len(mine) else f"[red]{n_ok}/{len(mine)}[/red]")
        t.add_row(*row)
    con.print(t)
    for f in summary["failures"]:
        con.print(f"[red]{f['sequence']} {f['stage']} {f['status']}:[/red] {f['error']}", soft_wrap=True)
    reports = {k: EvalReport.from_json_dict(v) for k, v in summary["evaluation"].items() if v["per_sequence"]}
    if reports:
        con.print("pooled over the sequences evaluated (sum of counts over all frames, then ratios):")
        print_comparison(reports, "kf" if "kf" in reports else None, con)
    warned = [(k, r["warnings"]) for k, r in results.items() if r.get("warnings")]
    if warned:
        con.print(f"[yellow]{len(warned)} task(s) warned[/yellow] (first: {warned[0][0]}: {warned[0][1][0]}); "
                  f"every warning is in {plan.folder / 'run.json'}", soft_wrap=True)
    n = len(results)
    failed = sum(r["status"] == "failed" for r in results.values())
    skipped = sum(r["status"] == "skipped" for r in results.values())
    con.print(f"{n} tasks: {outcome.n_ok - outcome.n_reused} computed, {outcome.n_reused} already done, {failed} failed, "
              f"{skipped} skipped -> {plan.folder / 'summary.json'} ({plan.runs / 'latest'})")
    if outcome.n_ok == 0:
        return 2
    return 1 if failed or skipped else 0
