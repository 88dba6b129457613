"""Domain parameters θ and families Θ: validation with named fields, seeded sampling."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams, ParamSpace, ParamSpaceError

# ---------------------------------------------------------------------------------------------------
# DomainParams


def test_defaults_and_derived_quantities():
    p = DomainParams()
    assert (p.image_width, p.image_height) == (640, 480)
    assert p.physics_rate == 60.0 and p.frame_rate == 15.0
    assert p.substeps == 4
    assert p.physics_dt == pytest.approx(1 / 60)
    assert p.delay_ticks == 3  # 0.05 s at 60 Hz
    assert DomainParams(delay_jitter=0.1).jitter_ticks == 6


@pytest.mark.parametrize("key", ["trimm", "imagewidth", "Trim"])
def test_unknown_key_rejected_naming_it(key):
    with pytest.raises(ValidationError) as exc_info:
        DomainParams(**{key: 0.1})
    assert f"unknown domain parameter {key!r}" in exc_info.value.errors()[0]["msg"]


def test_unknown_key_rejected_by_model_validate_and_replace():
    with pytest.raises(ValidationError, match="light_rbg"):
        DomainParams.model_validate({"light_rbg": (1, 1, 1)})
    with pytest.raises(ValidationError, match="comand_delay"):
        DomainParams().replace(comand_delay=0.1)


@pytest.mark.parametrize(
    "physics_rate, frame_rate", [(50.0, 15.0), (10.0, 15.0), (61.0, 15.0), (100.0, 30.0)]
)
def test_physics_rate_must_be_a_whole_multiple_of_frame_rate(physics_rate, frame_rate):
    with pytest.raises(ValidationError) as exc_info:
        DomainParams(physics_rate=physics_rate, frame_rate=frame_rate)
    msg = str(exc_info.value)
    assert "physics_rate" in msg and "whole multiple of frame_rate" in msg
    assert f"{physics_rate:g} Hz" in msg and f"{frame_rate:g} Hz" in msg


@pytest.mark.parametrize("physics_rate, frame_rate, substeps", [(60.0, 60.0, 1), (120.0, 30.0, 4), (45.0, 15.0, 3)])
def test_whole_multiples_accepted(physics_rate, frame_rate, substeps):
    assert DomainParams(physics_rate=physics_rate, frame_rate=frame_rate).substeps == substeps


@pytest.mark.parametrize(
    "field, value",
    [("trim", 1.5), ("gain", 0.0), ("command_delay", -0.1), ("image_width", 4), ("motor_deadband", 1.0),
     ("dynamics", "magic"), ("camera_fov_y", 180.0), ("light_rgb", (1.0, 1.0))],
)
def test_out_of_range_values_name_the_field(field, value):
    with pytest.raises(ValidationError) as exc_info:
        DomainParams(**{field: value})
    assert exc_info.value.errors()[0]["loc"][0] == field


def test_frozen_and_replace_validates():
    p = DomainParams(trim=0.1)
    with pytest.raises(ValidationError):
        p.trim = 0.2
    q = p.replace(command_delay=0.2)
    assert q.command_delay == 0.2 and q.trim == 0.1 and p.command_delay == 0.05
    with pytest.raises(ValidationError, match="trim"):
        p.replace(trim=3.0)
    assert p == DomainParams(trim=0.1)
    assert hash(p) == hash(DomainParams(trim=0.1))


def test_field_names():
    names = DomainParams.field_names()
    assert "trim" in names and "camera_pitch" in names
    assert set(STRUCTURAL_FIELDS) <= set(names)


# ---------------------------------------------------------------------------------------------------
# ParamSpace


def space_error(dists) -> str:
    with pytest.raises(ParamSpaceError) as exc_info:
        ParamSpace.from_dict(dists)
    return str(exc_info.value)


def test_unknown_field():
    assert "'trimm'" in space_error({"trimm": {"uniform": [0, 1]}})


def test_bad_distribution():
    msg = space_error({"trim": {"gauss": [0, 1]}})
    assert msg.startswith("trim:") and "'gauss'" in msg


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ([0, 1], "expected one of"),
        ({"uniform": [0, 1], "normal": [0, 1]}, "expected one of"),
        ({"uniform": [0.2]}, "takes two finite numbers"),
        ({"uniform": [0, float("inf")]}, "takes two finite numbers"),
        ({"normal": [0, -1]}, "std must be >= 0"),
        ({"choice": []}, "at least one value"),
    ],
)
def test_malformed_specs_name_the_field(spec, fragment):
    msg = space_error({"trim": spec})
    assert msg.startswith("trim:") and fragment in msg


@pytest.mark.parametrize("kind", ["uniform", "loguniform"])
def test_low_above_high(kind):
    msg = space_error({"gain": {kind: [2.0, 1.0]}})
    assert msg.startswith("gain:") and "low 2.0 is above high 1.0" in msg


def test_loguniform_needs_positive_bounds():
    assert space_error({"gain": {"loguniform": [0.0, 1.0]}}).startswith("gain:")


@pytest.mark.parametrize("field", STRUCTURAL_FIELDS)
def test_structural_fields_cannot_be_randomised(field):
    msg = space_error({field: {"choice": [64]}})
    assert f"'{field}'" in msg and "structural" in msg


def test_values_that_cannot_validate_rejected_at_construction():
    msg = space_error({"trim": {"uniform": [2.0, 3.0]}})
    assert "invalid" in msg and "trim" in msg


def test_seeded_sampling_is_reproducible():
    space = ParamSpace.from_dict({
        "trim": {"uniform": [-0.2, 0.2]},
        "gain": {"loguniform": [0.5, 2.0]},
        "camera_pitch": {"normal": [19.15, 1.0]},
        "dynamics": {"choice": ["dynamic", "kinematic"]},
    })
    a = [space.sample(np.random.default_rng(42)) for _ in range(2)]
    assert a[0] == a[1]
    rng1, rng2 = np.random.default_rng(3), np.random.default_rng(3)
    seq1 = [space.sample(rng1) for _ in range(20)]
    seq2 = [space.sample(rng2) for _ in range(20)]
    assert seq1 == seq2
    # successive draws differ and stay in their ranges
    assert len({p.trim for p in seq1}) == 20
    assert all(-0.2 <= p.trim <= 0.2 and 0.5 <= p.gain <= 2.0 for p in seq1)
    assert {p.dynamics for p in seq1} == {"dynamic", "kinematic"}
    # unrandomised fields keep the base value
    assert all(p.command_delay == space.base.command_delay for p in seq1)


def test_sampling_order_independent_of_dict_order():
    d1 = {"trim": {"uniform": [-0.2, 0.2]}, "gain": {"uniform": [0.5, 2.0]}}
    d2 = dict(reversed(list(d1.items())))
    p1 = ParamSpace.from_dict(d1).sample(np.random.default_rng(0))
    p2 = ParamSpace.from_dict(d2).sample(np.random.default_rng(0))
    assert p1 == p2


def test_base_params_kept():
    base = DomainParams(image_width=80, image_height=60, trim=0.05)
    space = ParamSpace.from_dict({"gain": {"uniform": [0.9, 1.1]}}, base=base)
    p = space.sample(np.random.default_rng(0))
    assert (p.image_width, p.image_height, p.trim) == (80, 60, 0.05)


def test_rgb_fields_sampled_per_channel():
    space = ParamSpace.from_dict({"light_rgb": {"uniform": [0.8, 1.2]}, "road_rgb": {"normal": [50.0, 5.0]}})
    p = space.sample(np.random.default_rng(1))
    assert len(p.light_rgb) == 3 and len(set(p.light_rgb)) == 3
    assert all(0.8 <= c <= 1.2 for c in p.light_rgb)
    assert len(set(p.road_rgb)) == 3


def test_choice_on_rgb_field_picks_whole_colours():
    colours = [(10.0, 20.0, 30.0), (40.0, 50.0, 60.0)]
    space = ParamSpace.from_dict({"road_rgb": {"choice": colours}})
    seen = {space.sample(np.random.default_rng(s)).road_rgb for s in range(20)}
    assert seen == set(colours)


def test_to_dict_round_trip():
    d = {"trim": {"uniform": [-0.1, 0.1]}, "light_rgb": {"normal": [1.0, 0.1]}}
    space = ParamSpace.from_dict(d)
    assert space.to_dict() == d
    again = ParamSpace.from_dict(space.to_dict())
    assert again.sample(np.random.default_rng(5)) == space.sample(np.random.default_rng(5))
