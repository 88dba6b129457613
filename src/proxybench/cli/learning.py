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
from rich.progress import Progress

from proxybench.cli.app import app, console, fail
from proxybench.cli.help import HelpTyper
from proxybench.cli.options import non_negative, positive
from proxybench.cli.progress import stage_bars

learn_app = HelpTyper(no_args_is_help=True, help="Behaviour cloning: datasets, training, fine-tuning, evaluation.")
app.add_typer(learn_app, name="learn")


def _bars() -> Progress:
    return stage_bars(elapsed=True)


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
    from proxybench.learning.collection import CollectConfig, collect
    from proxybench.learning.domains import parse_domain

    try:
        dom = parse_domain(domain, width, height)
        cfg = CollectConfig(samples=samples, robots=robots, noise_std=noise, map=map_name, seed=seed)
    except ValueError as exc:
        raise fail(exc, 2) from exc
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
        raise fail(exc, 2) from exc
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
    from proxybench.learning.evaluation import EvalConfig, evaluate_expert, evaluate_policy

    try:
        agent = BCAgent(checkpoint)
        cfg = agent.model.cfg
        dom = parse_domain(domain, cfg.width, cfg.height)
    except (FileNotFoundError, ValueError) as exc:
        raise fail(exc, 2) from exc
    ecfg = EvalConfig(episodes=episodes, seconds=seconds, map=map_name)
    res = evaluate_policy(agent.policy, dom, ecfg)
    expert = evaluate_expert(dom, ecfg)
    what = "simulated stand-in for a real robot" if dom.kind == "reality-model" else "simulation"
    console.print(f"{agent.name} in {dom.name} ({what}): lane score {res.mean:.2f} over {episodes} × {seconds:g} s "
                  f"(per episode {', '.join(f'{x:.1f}' for x in res.scores)}; expert {expert.mean:.2f})",
                  highlight=False)
