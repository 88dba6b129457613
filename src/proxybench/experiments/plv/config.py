"""The settings of the PLV experiment (``proxybench plv``, and ``optimize --objective plv``'s ``plv:`` section).

:class:`PLVConfig` is a strict study config: every field documented, unknown keys refused; the nested
sections (``model``, ``train``, ``pretrain``, ``finetune``, ``collect``, ``eval``, ``dagger``) are the settings
of behaviour cloning (:mod:`proxybench.learning.configs`) and merge key by key with the file's and the
command line's. Importing it needs neither PyTorch nor the simulator, so the command line is generated from it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field, ValidationError, model_validator

from proxybench.experiments.study import Cli, StudyConfig
from proxybench.learning.configs import CollectConfig, EvalConfig, ModelConfig, TrainConfig
from proxybench.targets.manifest import format_errors

if TYPE_CHECKING:  # imported when used: usefulness/ loads scipy
    from proxybench.usefulness.plv import DataCost

__all__ = ["THESIS_PROXIES", "DaggerConfig", "PLVConfig"]

#: the thesis' proxies (camera pitch 3°, 19°, 35°) and a domain-randomised family
THESIS_PROXIES: dict[str, str] = {
    "pitch 3°": "proxy:camera_pitch=3",
    "pitch 19°": "proxy:camera_pitch=19",
    "pitch 35°": "proxy:camera_pitch=35",
    "randomized": "randomized",
}
_CACHE_FORMAT = 2  # 2: one pre-training per seed


@dataclass(frozen=True)
class DaggerConfig:
    """``rounds`` of on-policy collection; in round r the expert's command is executed with probability
    ``beta · beta_decay^r`` (β = 0: the learner always drives)."""

    rounds: int = 2
    beta: float = 0.0
    beta_decay: float = 0.5

    def __post_init__(self) -> None:
        if self.rounds < 1:
            raise ValueError(f"DAgger needs at least one round, got {self.rounds}")


class PLVConfig(StudyConfig):
    """Every knob of the experiment; ``quick()`` is the few-minutes version for tests and first tries."""

    width: int = 64
    """network input and camera image width [px]"""
    height: int = 48
    """network input and camera image height [px]"""
    ladder: tuple[int, ...] = (50, 100, 250, 500, 1000, 2000, 4000, 9000)
    """target samples of each rung (cost units with DAgger): the thesis' 250 … 9,000, plus 50 and 100 to resolve
    small needs"""
    seeds: Annotated[tuple[int, ...], Cli(count=True)] = tuple(range(15))
    """training seeds per arm (target-data subset, initialisation and minibatch order; for a proxy, also its
    pre-training); 15: the fitted curves' bootstrap intervals hold the true PLV in about 9 of 10 simulated
    experiments (docs/learning.md). On the command line a count N: seeds 0 … N−1"""
    proxies: Annotated[dict[str, str], Cli("--proxy", metavar="NAME=DOMAIN")] = Field(
        default_factory=lambda: dict(THESIS_PROXIES))
    """a proxy: its name and domain (proxy[:NAME=VALUE,...] | randomized | family.yaml)"""
    proxy_samples: int = 20_000
    """expert-driven frames of each proxy's pre-training data"""
    tolerance: float = 0.05
    """the reference P is the converged target-only score less this share of it; a curve must reach P and stay"""
    confirm: int = 2
    """rungs after the first one at or above P that must stay above it (the ladder's end counts)"""
    stop_when_reached: bool = True
    """stop a proxy's ladder once it has settled above P (else run it all)"""
    replicates: int = 4000
    """bootstrap replicates over seeds for the intervals"""
    model: ModelConfig = Field(default_factory=ModelConfig)
    """the network (its input size is width × height)"""
    train: TrainConfig = Field(default_factory=lambda: TrainConfig(epochs=10.0, min_steps=100, max_steps=1000))
    """target-only training from scratch (10 epochs, at least 100 and at most 1,000 steps of 64: fits 45 min on 2
    cores)"""
    pretrain: TrainConfig = Field(default_factory=lambda: TrainConfig(epochs=3.0, min_steps=100, max_steps=1000))
    """pre-training on a proxy's data"""
    finetune: TrainConfig = Field(default_factory=lambda: TrainConfig(epochs=10.0, min_steps=100, max_steps=1000,
                                                                      lr=3e-4))
    """fine-tuning a pre-trained network on target samples"""
    collect: CollectConfig = Field(default_factory=lambda: CollectConfig(samples=1))
    """how the expert records data (the number of samples is set per use)"""
    eval: EvalConfig = Field(default_factory=lambda: EvalConfig(episodes=10, seconds=30.0))
    """evaluation episodes in the target"""
    use_dagger: Annotated[bool, Cli("--dagger")] = False
    """spend on_fraction of every rung on on-policy (DAgger) target samples"""
    on_fraction: float = 0.5
    """share of a rung collected on-policy with DAgger"""
    dagger: Annotated[DaggerConfig, Cli("--dagger-settings")] = Field(default_factory=DaggerConfig)
    """DAgger's rounds and expert share"""
    eta_on: float = Field(1.0, gt=0.0, allow_inf_nan=False)
    """cost of one on-policy target sample (generalised PLV)"""
    eta_off: float = Field(1.0, gt=0.0, allow_inf_nan=False)
    """cost of one off-policy (expert-driven) target sample"""
    seed: int = 0
    """seed of the data collections"""
    target: str = "reality"
    """reality (the reality model) or robot:COMMAND (a robot node: target samples are collected on it, the expert
    reading the true lane pose it serves, and every network is scored on it)"""

    @model_validator(mode="after")
    def _checked(self) -> PLVConfig:
        if sorted(self.ladder) != list(self.ladder) or not self.ladder or self.ladder[0] < 1:
            raise ValueError(f"the ladder must be increasing positive sample counts, got {self.ladder}")
        if not 0.0 <= self.on_fraction <= 1.0:
            raise ValueError(f"on_fraction must be in [0, 1], got {self.on_fraction}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct and at least one, got {self.seeds}")
        if self.confirm < 0:
            raise ValueError(f"confirm must be >= 0, got {self.confirm}")
        if self.target != "reality" and not self.target.startswith("robot:"):
            raise ValueError(f"target must be 'reality' or 'robot:COMMAND', got {self.target!r}")
        if (self.model.width, self.model.height) != (self.width, self.height):
            # the network takes the experiment's frames: set once here (the model is frozen afterwards)
            object.__setattr__(self, "model", replace(self.model, width=self.width, height=self.height))
        return self

    @classmethod
    def quick(cls) -> PLVConfig:
        """40×30 frames, three seeds, a short ladder and short training: minutes on two cores."""
        return cls(width=40, height=30, ladder=(150, 400, 1000, 2500), seeds=(0, 1, 2), proxy_samples=4000,
                   replicates=2000,
                   train=TrainConfig(epochs=10.0, min_steps=60, max_steps=400),
                   pretrain=TrainConfig(epochs=4.0, min_steps=60, max_steps=300),
                   finetune=TrainConfig(epochs=10.0, min_steps=60, max_steps=400, lr=3e-4),
                   eval=EvalConfig(episodes=4, seconds=15.0))

    def split(self, n: int) -> DataCost:
        """How a rung of ``n`` target samples is collected: off-policy (expert) and on-policy (DAgger)."""
        from proxybench.usefulness.plv import DataCost

        on = round(n * self.on_fraction) if self.use_dagger else 0
        return DataCost(n - on, on)

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump()

    @classmethod
    def from_dict(cls, d: dict[str, Any], base: PLVConfig | None = None) -> PLVConfig:
        """A config from JSON-like data; keys not given keep ``base``'s values (sections key by key); unknown keys
        are errors."""
        unknown = [k for k in d if k not in cls.model_fields]
        if unknown:
            raise ValueError(f"unknown PLV setting {unknown[0]!r}; known: {', '.join(sorted(cls.model_fields))}")
        cur = (base or cls()).to_dict()
        merged = {k: {**cur[k], **v} if k in cls.sections() and isinstance(v, dict) else v for k, v in d.items()}
        try:
            return cls.model_validate({**cur, **merged})
        except ValidationError as exc:
            raise ValueError("; ".join(line.removeprefix("PLV: ") for line in
                                       format_errors(exc, "PLV", cls).splitlines())) from None

    def work_key(self) -> str:
        """Hash of what a training run's result depends on (not the ladder, seeds, proxy list or tolerance)."""
        d = self.to_dict()
        for k in ("ladder", "seeds", "proxies", "tolerance", "confirm", "stop_when_reached", "eta_on", "eta_off",
                  "replicates"):
            d.pop(k)
        d["cache_format"] = _CACHE_FORMAT
        if d["target"] == "reality":  # the key the reality model's runs had before targets were configurable
            d.pop("target")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:12]


