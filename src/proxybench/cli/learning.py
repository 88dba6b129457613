"""`proxybench plv` and `proxybench learn ...`: behaviour cloning and the proxy learning value (PLV).

Everything here needs PyTorch (the ``learning`` extra); it is imported inside the commands, so the
rest of the command line works without it (``plv``'s options come from :class:`PLVConfig`, which needs neither
PyTorch nor the simulator).
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import Progress
from rich.table import Table

from proxybench.cli.app import app, console, err_console
from proxybench.cli.config_options import mode_defaults, study_options
from proxybench.cli.options import non_negative, positive
from proxybench.cli.progress import stage_bars, stage_progress
from proxybench.cli.studies import BackendOption, WorkersOption, run_study
from proxybench.cli.usefulness import experiment_options
from proxybench.experiments.config import ExperimentConfig
from proxybench.experiments.plv.config import PLVConfig

learn_app = typer.Typer(no_args_is_help=True, help="Behaviour cloning: datasets, training, fine-tuning, evaluation.")
app.add_typer(learn_app, name="learn")


def _bars() -> Progress:
    return stage_bars(elapsed=True)


def _fail(msg: str, code: int = 2) -> typer.Exit:
    err_console.print(f"[red]error:[/red] {escape(str(msg))}", highlight=False)
    return typer.Exit(code)


def _load_plv(path: Path | None, overrides: dict, own: dict) -> PLVConfig:
    """The file and the options over ``PLVConfig()``, or with ``--quick`` over ``PLVConfig.quick()``."""
    base = PLVConfig.quick() if own["quick"] else PLVConfig()
    return PLVConfig.load(path, overrides, base=base.to_dict())


def _plv_defaults() -> dict[str, str]:
    full, quick = PLVConfig(), PLVConfig.quick()
    return mode_defaults(full.to_dict(), quick.to_dict()) | {"seeds": f"{len(full.seeds)}; --quick {len(quick.seeds)}"}


@app.command()
@study_options(PLVConfig, load=_load_plv, defaults=_plv_defaults(),
               config_help="YAML or JSON file of PLVConfig fields (sections: train: {max_steps: 100}, eval, ...)")
def plv(
    cfg: PLVConfig,
    quick: bool = typer.Option(False, "--quick", help="40×30 frames, short ladder, 3 seeds (minutes)"),
    out: Path = typer.Option(Path("out/plv"), help="report folder (figure, tables, report.html) and cache"),
) -> None:
    """How many target samples does pre-training on a proxy save a behaviour-cloning agent? (Table 3.1, Fig. 3.6)

    The target is the reality model, a *simulated* stand-in for a real Duckiebot, or a robot node (--target);
    the proxies are the simulator with camera pitch 3°, 19°, 35° and a domain-randomised family. PLV comes from
    fitted learning curves (a continuous crossing of P) with bootstrap intervals over seeds; the ladder rule is
    shown beside it. Work is cached in OUT/cache, so an interrupted run resumes.
    """
    from proxybench.experiments.plv.report import findings, summarize, table_rows, write_report
    from proxybench.experiments.plv.run import run_plv
    from proxybench.protocol import RobotFailure

    t0 = time.perf_counter()
    with _bars() as bar:
        try:
            res = run_plv(cfg, out, stage_progress(bar))
        except (RuntimeError, RobotFailure) as exc:  # a robot node that fails or serves no lane pose
            raise _fail(f"{cfg.target}: {exc}") from exc
    files = write_report(res, out)
    s = summarize(res)
    wall = time.perf_counter() - t0
    note = f", {res.cached} units from the cache" if res.cached else ""
    rows = table_rows(res, s)
    table = Table(title=f"Table 3.1 — PLV of proxies (target: {s.target_label}) — {len(cfg.seeds)} seeds, fitted "
                        f"curves, 95 % bootstrap intervals over seeds — {wall:.0f} s{note}")
    for col in rows[0]:
        table.add_column(col, justify="left" if col == "domain" else "right")
    for r in rows:
        table.add_row(*(escape(str(v)) for v in r.values()))  # "[not reached, 900]" is not markup
    console.print(table)
    for line in findings(res, s):
        console.print(f"• {escape(line)}", highlight=False)
    console.print(f"wrote {files['html']}, {files['fig3_6']} and {files['fig_plv']} (+ .svg), {files['table']}, "
                  f"{files['runs']}", highlight=False)


@learn_app.command("dataset")
def learn_dataset(
    domain: str = typer.Argument(..., help="reality | proxy[:NAME=VALUE,...] | randomized | family.yaml"),
    out: Path = typer.Option(..., help="dataset folder (NPZ shards + dataset.json)"),
    samples: int = typer.Option(5000, min=1),
    width: int = typer.Option(64, min=8, max=4096, help="image width [px]"),
    height: int = typer.Option(48, min=8, max=4096, help="image height [px]"),
    robots: int = typer.Option(32, min=1, help="robots driven at once by the batched simulator"),
    noise: float = typer.Option(0.15, callback=non_negative,
                                help="std of the noise added to the executed expert command [PWM]"),
    map_name: str = typer.Option("loop_3x3", "--map"),
    seed: int = typer.Option(0, min=0),
) -> None:
    """Let the privileged expert drive DOMAIN (with recovery noise) and record camera frames + its commands."""
    from proxybench.learning.domains import parse_domain
    from proxybench.runner.collect import CollectConfig, collect

    try:
        dom = parse_domain(domain, width, height)
        cfg = CollectConfig(samples=samples, robots=robots, noise_std=noise, map=map_name, seed=seed)
    except ValueError as exc:
        raise _fail(str(exc)) from exc
    t0 = time.perf_counter()
    with _bars() as bar:
        task = bar.add_task(f"expert driving {dom.name}", total=samples)
        data = collect(dom, cfg, progress=lambda d, t: bar.update(task, completed=d))
    data.save(out)
    wall = time.perf_counter() - t0
    console.print(f"wrote {out}: {len(data):,} samples, {len(data.meta['episodes'])} episodes, "
                  f"{len(data.meta['thetas'])} θ ({len(data) / wall:,.0f} samples/s)")


@learn_app.command("train")
def learn_train(
    data: list[Path] = typer.Argument(..., help="dataset folder(s)"),
    out: Path = typer.Option(..., help="checkpoint path (NAME.pt; NAME.json is written beside it)"),
    init: Path | None = typer.Option(None, help="fine-tune this checkpoint instead of starting from scratch"),
    samples: int | None = typer.Option(None, min=1, help="use only this many samples (whole episodes, seeded)"),
    epochs: float = typer.Option(15.0, callback=positive),
    max_steps: int = typer.Option(2000, min=1),
    lr: float | None = typer.Option(None, callback=positive,
                                    help="learning rate (default 1e-3 from scratch, 3e-4 fine-tuning)"),
    output: str = typer.Option("wheels", help="wheels (PWM) | vw (v, ω) — from scratch only"),
    seed: int = typer.Option(0, min=0),
) -> None:
    """Train a PilotNet-style network on expert data (or fine-tune a checkpoint) and save a checkpoint."""
    from proxybench.learning.dataset import Dataset, DatasetError
    from proxybench.learning.model import ModelConfig, configure_threads
    from proxybench.learning.training import TrainConfig, build_model, load_checkpoint, save_checkpoint, train

    configure_threads()
    try:
        ds = Dataset.concat([Dataset.load(p) for p in data])
        ds = ds.take(samples, seed) if samples else ds
        if init:
            model, prior = load_checkpoint(init)
        else:
            w, h = ds.image_size
            model, prior = build_model(ModelConfig(width=w, height=h, output=output), seed), {}
    except (DatasetError, FileNotFoundError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    cfg = TrainConfig(epochs=epochs, max_steps=max_steps, lr=lr or (3e-4 if init else 1e-3), seed=seed)
    with _bars() as bar:
        task = bar.add_task("fine-tuning" if init else "training", total=cfg.steps_for(len(ds)))
        res = train(model, ds, cfg, progress=lambda s, t: bar.update(task, completed=s))
    info = {"train": {"config": asdict(cfg), "losses": res.losses, "wall_s": res.wall_s},
            "data": {"folders": [str(p) for p in data], "samples": len(ds), "domain": ds.meta.get("domain")},
            "init": str(init) if init else None, "prior": prior.get("data")}
    path = save_checkpoint(out, model, info)
    console.print(f"wrote {path} (+ .json): {res.steps} steps on {len(ds):,} samples, loss {res.losses[0]:.4f} → "
                  f"{res.losses[-1]:.4f}, {res.samples_per_s:,.0f} samples/s on {res.device}")


@learn_app.command("evaluate")
def learn_evaluate(
    checkpoint: Path = typer.Argument(..., help="checkpoint (.pt with its .json)"),
    domain: str = typer.Option("reality", help="reality | proxy[:NAME=VALUE,...] | randomized | family.yaml"),
    episodes: int = typer.Option(6, min=1),
    seconds: float = typer.Option(30.0, callback=positive),
    map_name: str = typer.Option("loop_3x3", "--map"),
) -> None:
    """Lane score of a checkpoint over evaluation episodes (all episodes in one batched simulator)."""
    from proxybench.learning.agent import BCAgent
    from proxybench.learning.domains import parse_domain
    from proxybench.runner.policy_eval import EvalConfig, evaluate_expert, evaluate_policy

    try:
        agent = BCAgent(checkpoint)
        cfg = agent.model.cfg
        dom = parse_domain(domain, cfg.width, cfg.height)
    except (FileNotFoundError, ValueError) as exc:
        raise _fail(str(exc)) from exc
    ecfg = EvalConfig(episodes=episodes, seconds=seconds, map=map_name)
    res = evaluate_policy(agent.policy, dom, ecfg)
    expert = evaluate_expert(dom, ecfg)
    what = "simulated stand-in for a real robot" if dom.kind == "reality-model" else "simulation"
    console.print(f"{agent.name} in {dom.name} ({what}): lane score {res.mean:.2f} over {episodes} × {seconds:g} s "
                  f"(per episode {', '.join(f'{x:.1f}' for x in res.scores)}; expert {expert.mean:.2f})",
                  highlight=False)


@app.command("plv-vs-prpv")
@experiment_options("predictivity", exclude=("search", "plan", "pod_seconds", "truth", "dtps_options"),
                    defaults={"sweep": "camera_pitch=12,19.15,26 (one parameter changed at a time)"})
def plv_vs_prpv(
    cfg: ExperimentConfig,
    quick: bool = typer.Option(False, "--quick", help="the quick predictivity defaults and PLVConfig.quick()"),
    out: Path = typer.Option(Path("out/plv-vs-prpv"), help="folder for choice.json/.csv/.png and the caches"),
    backend: BackendOption = "local",
    workers: WorkersOption = None,
) -> None:
    """Do the two uses of a simulator pick the same θ? argmin PRPV (predict) and argmax PLV (teach) on one target.

    For every candidate θ: PRPV of the agents' replays with its order range and the paired difference to the
    lowest, and PLV of a network pre-trained on it (fitted curves) with its interval; then both picks and their
    tied sets (docs/learning.md). Work is cached in OUT, so an interrupted run resumes.
    """
    from proxybench.experiments.optimize.plv_search import torch_available
    from proxybench.experiments.plv_prpv.report import table_rows, write_choice
    from proxybench.experiments.plv_prpv.run import run_plv_prpv
    from proxybench.protocol import RobotFailure

    if not torch_available():
        raise _fail("PLV needs PyTorch: pip install -e '.[learning]'")
    t0 = time.perf_counter()
    try:
        res = run_study(backend, workers, lambda be, progress: run_plv_prpv(cfg, out, quick=quick, backend=be,
                                                                           progress=progress))
    except (RuntimeError, RobotFailure) as exc:
        raise _fail(str(exc)) from exc
    wall = time.perf_counter() - t0
    files = write_choice(res, out, wall)
    rows = table_rows(res)
    table = Table(title=f"predict (argmin PRPV) vs teach (argmax PLV) — {len(res.agents)} agents × {res.episodes} "
                        f"episodes; PLV over {res.plv_seeds} seeds; {wall:.0f} s")
    for col in rows[0]:
        table.add_column(escape(col), justify="left" if col == "candidate θ" else "right")
    for r in rows:
        table.add_row(*(escape(str(v)) for v in r.values()))
    console.print(f"[bold]target:[/bold] {escape(res.target)}", highlight=False)
    console.print(table)
    console.print(f"• argmin PRPV: {res.prpv_pick} (not separated from it: {', '.join(res.prpv_tied)}); argmax PLV: "
                  f"{res.plv_pick or 'none'} (intervals reaching it: {', '.join(res.plv_tied) or '–'})",
                  highlight=False, markup=False)
    console.print(f"• {res.verdict()}", highlight=False, markup=False)
    console.print(f"wrote {files['json']}, {files['csv']}, {files['png']} (+ .svg)", highlight=False)
