"""Byte level: envelopes and typed messages against the recorded AIDO exchange, the stream reader, JPEG."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import cbor2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from proxybench.domain.lane_pose import LanePose
from proxybench.protocol import jpeg, wire
from proxybench.protocol.description import declares_extension, decode_extras, encode_extras, protocol_description
from proxybench.protocol.language import AgentLanguage

# a copy of the reply recorded from the real node (shared/aido/protocol-description.json), kept with the tests
AIDO = Path(__file__).resolve().parent / "data" / "aido"

# recorded with zuper-nodes-z6 6.2.17 (shared/aido/wire-capture.txt, wire-errors.txt)
CAPABILITIES = ("a267636f6e74726f6c6c6361706162696c69746965736464617461a1627a32a17370726f746f636f6c2d7265666c6563"
                "74696f6ef5")
UNDERSTOOD = "a267636f6e74726f6c6a756e64657273746f6f646464617461f6"
OVER = "a267636f6e74726f6c646f7665726464617461f6"
DESCRIBE = ("a466636f6d70617481627a3265746f7069637819777261707065722e64657363726962655f70726f746f636f6c6464617461f6"
            "6674696d696e67f6")
DESCRIPTION_HEAD = ("a466636f6d70617481627a3265746f7069637470726f746f636f6c5f6465736372697074696f6e6464617461a2646461"
                    "7461")
SEED_42 = "a466636f6d70617481627a3265746f70696364736565646464617461182a6674696d696e67f6"
EPISODE_000 = ("a466636f6d70617481627a3265746f7069636d657069736f64655f73746172746464617461a26c657069736f64655f6e616d"
               "656565703030306c79616d6c5f7061796c6f6164627b7d6674696d696e67f6")
GET_COMMANDS = {
    0.0: "a466636f6d70617481627a3265746f7069636c6765745f636f6d6d616e64736464617461a16761745f74696d65fb0000000000000000"
         "6674696d696e67f6",
    0.05: "a466636f6d70617481627a3265746f7069636c6765745f636f6d6d616e64736464617461a16761745f74696d65fb3fa999999999999a"
          "6674696d696e67f6",
}
OBSERVATIONS_HEAD = ("a466636f6d70617481627a3265746f7069636c6f62736572766174696f6e736464617461a26663616d657261a2686a70")
COMMANDS = (
    "a466636f6d70617481627a3265746f70696368636f6d6d616e64736464617461a2644c454453a56663656e746572a36162fb3ff0000000"
    "0000006167fb00000000000000006172fb0000000000000000696261636b5f6c656674a36162fb3ff00000000000006167fb000000000000"
    "00006172fb00000000000000006a6261636b5f7269676874a36162fb3ff00000000000006167fb00000000000000006172fb000000000000"
    "00006a66726f6e745f6c656674a36162fb3ff00000000000006167fb00000000000000006172fb00000000000000006b66726f6e745f7269"
    "676874a36162fb3ff00000000000006167fb00000000000000006172fb000000000000000066776865656c73a26a6d6f746f725f6c656674"
    "fb3fd19bbc71e3c0b66b6d6f746f725f7269676874fb3fd4caa9f482a5b06674696d696e67a16970726f636573736564a1656167656e74a4"
    "6474696d65a261731a6b02de196275731a2123662e65636c6f636b62766d656672616d656565706f63686574696d6532a261731a6b02de19"
    "6275731a212a3957"
)
COMMANDS_TIMING = (1795350041 * 10**9 + 555968046, 1795350041 * 10**9 + 556415319)


def messages(data: bytes) -> list[dict]:
    stream = wire.CborStream()
    stream.feed(data)
    stream.feed_eof()
    out = []
    while (m := stream.next()) is not None:
        out.append(m)
    return out


# ------------------------------------------------------------------------------------------ envelopes
def test_control_messages_match_capture():
    assert wire.encode_control("capabilities", wire.CAPABILITIES).hex() == CAPABILITIES
    assert wire.encode_control(wire.CTRL_UNDERSTOOD).hex() == UNDERSTOOD
    assert wire.encode_control(wire.CTRL_OVER).hex() == OVER


def test_caller_messages_match_capture():
    assert wire.encode_topic("wrapper.describe_protocol", None).hex() == DESCRIBE
    assert wire.encode_seed(42).hex() == SEED_42
    assert wire.encode_episode_start("ep000", "{}").hex() == EPISODE_000
    for t, expected in GET_COMMANDS.items():
        assert wire.encode_get_commands(t).hex() == expected
    obs = wire.encode_observations(b"\xff" * 11913, 0.0, (0.0, 0.0), 0.046542113386515455)
    assert obs.hex().startswith(OBSERVATIONS_HEAD) and len(obs) == 12097  # capture: jpg 11913 B → 12097 B


def test_commands_match_capture_byte_for_byte():
    timing = wire.node_timing("agent", *COMMANDS_TIMING)
    data = wire.encode_commands(0.2751303779796318, 0.3248696220203682, timing)
    assert data.hex() == COMMANDS
    assert timing["processed"]["agent"]["time"]["us"] == 555968046  # nanoseconds, as the real node sends
    # the node's fast path: timing encoded from cached pieces, the same bytes
    assert wire.encode_node_timing("agent", *COMMANDS_TIMING) == cbor2.dumps(timing)
    assert wire.encode_commands(0.2751303779796318, 0.3248696220203682,
                                wire.encode_node_timing("agent", *COMMANDS_TIMING)).hex() == COMMANDS


_floats = st.floats() | st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 1e308])
_times = st.integers(0, 2**64 - 1) | st.integers(1_700_000_000 * 10**9, 1_900_000_000 * 10**9)


@settings(max_examples=300, deadline=None)
@given(_floats, _floats, _floats, st.none() | st.tuples(_floats, _floats), st.none() | _floats,
       st.binary(max_size=300) | st.sampled_from([b"\xff" * n for n in (23, 24, 255, 256, 65535, 65536)]),
       st.none() | st.dictionaries(st.text(max_size=5), st.floats(), max_size=3), _times, _times,
       st.text(max_size=30))
def test_piece_built_messages_equal_cbor2_encoding_of_their_dicts(left, right, stamp, odometry, resolution, jpg,
                                                                  extras, t0, t1, node):
    """The per-step encoders build bytes from cached pieces; they must be exactly what cbor2 writes for the
    message's dict (every float width cbor2 picks, every length header size, NaN, ±inf, -0.0)."""
    assert wire.encode_get_commands(stamp) == wire.encode_topic("get_commands", {"at_time": stamp})
    assert wire.encode_observations(jpg, stamp, odometry, resolution, extras) == wire.encode_topic(
        "observations", wire.observations_data(jpg, stamp, odometry, resolution, extras))
    timing = wire.node_timing(node, t0, t1)
    assert wire.encode_node_timing(node, t0, t1) == cbor2.dumps(timing)
    expected = wire.encode_topic("commands", {"LEDS": wire.DEFAULT_LEDS, "wheels": {"motor_left": left,
                                                                                    "motor_right": right}}, timing)
    assert wire.encode_commands(left, right, wire.encode_node_timing(node, t0, t1)) == expected
    assert wire.encode_commands(left, right, timing) == expected


def test_describe_protocol_reply_matches_capture():
    timing = {"processed": {"agent.wrapper": {"time": {"s": 1795350041, "us": 475048303}, "clock": "vm",
                                              "frame": "epoch", "time2": {"s": 1795350041, "us": 475435018}}}}
    data = wire.encode_topic("protocol_description", protocol_description(), timing)
    assert len(data) == 11814 and data.hex().startswith(DESCRIPTION_HEAD)


def test_description_equals_recorded_json_including_key_order():
    recorded = json.loads((AIDO / "protocol-description.json").read_text())
    assert json.dumps(protocol_description()) == json.dumps(recorded)


def test_privileged_description_declares_extension_only_when_privileged():
    assert not declares_extension(protocol_description(False))
    desc = protocol_description(True)
    assert declares_extension(desc)
    obs = desc["data"]["inputs"]["observations"]
    assert obs["required"] == ["camera", "odometry"] and obs["order"] == ["camera", "odometry"]
    assert not declares_extension({"data": {}}) and not declares_extension(None)


def test_extras_roundtrip_lane_pose():
    lp = LanePose(True, 3, 0.25, -0.031, 0.12, True, False, True, True, True, (1, 2), 1.7)
    extras = encode_extras(lp)
    assert decode_extras(cbor2.loads(cbor2.dumps(extras))) == lp
    assert all(type(extras["lane_pose"][k]) is float for k in ("along", "lateral", "heading_error", "curvature"))
    assert decode_extras(encode_extras(None)) is None and decode_extras(None) is None
    with pytest.raises(TypeError):
        decode_extras({"lane_pose": {"valid": True}})


def test_decode_message_kinds():
    assert wire.decode_message({"control": "over", "data": None}) == wire.Control("over", None)
    msg = wire.decode_message({"topic": "seed", "data": 3, "timing": None})
    assert isinstance(msg, wire.Topic) and not msg.z2
    with pytest.raises(wire.BadMessageError):
        wire.decode_message({"hello": 1})
    with pytest.raises(wire.BadMessageError):
        wire.decode_message({"control": 3})


def test_timespec_reads_nanoseconds_and_microseconds():
    assert wire.timespec_seconds({"s": 10, "us": 555968046}) == pytest.approx(10.555968046)
    assert wire.timespec_seconds({"s": 10, "us": 500_000}) == pytest.approx(10.5)


# ------------------------------------------------------------------------------------- typed messages
@pytest.mark.parametrize("value", [math.nan, math.inf, 1.5, -1.0001, "fast", True, None])
def test_parse_commands_rejects(value):
    with pytest.raises(wire.MessageTypeError):
        wire.parse_commands({"wheels": {"motor_left": value, "motor_right": 0.0}})


def test_parse_commands_accepts_floats_and_ints():
    assert wire.parse_commands({"wheels": {"motor_left": -1.0, "motor_right": 1}}).tolist() == [-1.0, 1.0]
    with pytest.raises(wire.MessageTypeError):
        wire.parse_commands({"LEDS": {}})


def test_parse_inputs_are_strict_like_the_real_node():
    with pytest.raises(wire.MessageTypeError):
        wire.parse_get_commands({"at_time": 1})  # an int where a float is declared
    with pytest.raises(wire.MessageTypeError):
        wire.parse_seed(True)
    with pytest.raises(wire.MessageTypeError):
        wire.parse_observations({"camera": {"jpg_data": b"", "timestamp": 0.0}})  # no odometry
    assert wire.parse_episode_start({"episode_name": "e"}) == ("e", "{}")
    obs = wire.parse_observations(cbor2.loads(wire.encode_observations(b"x", 0.5, None, None))["data"])
    assert (obs.odometry, obs.resolution, obs.timestamp, obs.extras) == (None, None, 0.5, None)


# ------------------------------------------------------------------------------------- stream reader
def test_stream_reassembles_messages_split_at_every_byte():
    data = bytes.fromhex(UNDERSTOOD + COMMANDS + OVER)
    stream = wire.CborStream()
    got = []
    for i in range(len(data)):
        stream.feed(data[i:i + 1])
        while (m := stream.next()) is not None:
            got.append(m)
    assert [m.get("control", m.get("topic")) for m in got] == ["understood", "commands", "over"]
    assert stream.pending == 0


def test_stream_classifies_bad_input():
    cases = [
        (cbor2.dumps([1, 2, 3]), wire.NotAMapError),
        (cbor2.dumps(7), wire.NotAMapError),
        (b"\x1c\x00", wire.GarbageError),
        (b"\xff", wire.GarbageError),
        (b"hello world\n", wire.GarbageError),
        (b"\xa1\x62\xff\xfe\x01", wire.GarbageError),  # invalid UTF-8 key
    ]
    for data, error in cases:
        stream = wire.CborStream()
        stream.feed(data)
        with pytest.raises(error):
            stream.next()


def test_stream_truncated_only_at_eof():
    stream = wire.CborStream()
    stream.feed(bytes.fromhex(COMMANDS)[:100])
    assert stream.next() is None
    stream.feed_eof()
    with pytest.raises(wire.TruncatedError):
        stream.next()


def test_stream_indefinite_and_clean_eof():
    stream = wire.CborStream()
    stream.feed(b"\xbf\x61a\x9f\x01\x02\xff\xff" + bytes.fromhex(OVER))
    stream.feed_eof()
    assert stream.next() == {"a": [1, 2]}
    assert stream.next() == {"control": "over", "data": None}
    assert stream.next() is None


_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**64) + 1, 2**64 - 1) | st.floats() | st.text(max_size=30)
    | st.binary(max_size=300),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=30,
)


def test_stream_rejects_an_ill_formed_simple_value_but_not_its_bytes_inside_a_string():
    """cbor2 decodes ``f8 10`` (a two-byte simple value under 32, ill-formed) without complaint: the stream
    must still call it garbage, while the same two bytes inside a JPEG byte string are fine."""
    stream = wire.CborStream()
    stream.feed(b"\xa1\x61a\xf8\x10")
    with pytest.raises(wire.GarbageError, match="simple value"):
        stream.next()
    stream = wire.CborStream()
    stream.feed(b"\xa1\x61a\x43\xf8\x10\x00" + bytes.fromhex(OVER))
    assert stream.next() == {"a": b"\xf8\x10\x00"}
    assert stream.next() == {"control": "over", "data": None}
    hidden = [b"\xa1\x81\xf8\x10\x03",  # in an array used as a map key
              b"\xa1\x61a\xc6\xf8\x10",  # under a tag
              b"\xa1\x61a\xa1\x61b\x82\x01\xf8\x1f",  # deep in maps and arrays
              bytes.fromhex(OVER) + b"\xa1\x61a\xf8\x00"]  # decoded ahead after a good map
    for data in hidden:
        stream = wire.CborStream()
        stream.feed(data)
        with pytest.raises(wire.GarbageError, match="simple value"):
            while stream.next() is not None:
                pass
    stream = wire.CborStream()
    stream.feed(b"\xa1\x61a\x82\xf0\x43\xf8\x10\x00")  # a well-formed simple value beside the bytes
    assert stream.next() == {"a": [cbor2.CBORSimpleValue(16), b"\xf8\x10\x00"]}


@settings(max_examples=100, deadline=None)
@given(st.lists(st.dictionaries(st.text(max_size=8), _values, max_size=3), min_size=1, max_size=3),
       st.integers(16, 256), st.booleans())
def test_stream_returns_each_map_once_whatever_the_chunks(maps, chunk, half_floats):
    """Maps back to back, fed in arbitrary chunks, come out whole and in order; also for encodings cbor2
    would not write itself (half-width floats from a foreign encoder)."""
    parts = [cbor2.dumps(m) for m in maps]
    if half_floats:
        parts.append(b"\xa1\x61x\xf9\x3c\x00")  # {"x": 1.0} as a half float
        maps = [*maps, {"x": 1.0}]
    data = b"".join(parts)
    stream = wire.CborStream()
    got = []
    for i in range(0, len(data), chunk):
        stream.feed(data[i:i + chunk])
        while (m := stream.next()) is not None:
            got.append(m)
    assert len(got) == len(maps) and stream.pending == 0
    assert cbor2.dumps(got) == cbor2.dumps(maps)  # NaN-safe equality


@settings(max_examples=300, deadline=None)
@given(_values)
def test_item_end_finds_the_end_of_any_item(value):
    data = cbor2.dumps(value)
    assert wire.item_end(data + b"\x00trailing") == len(data)
    if len(data) > 1:
        assert wire.item_end(data[:-1]) == -1


# ------------------------------------------------------------------------------------------------ jpeg
def _image(h: int = 120, w: int = 160) -> np.ndarray:
    rng = np.random.default_rng(1)
    ramp = np.linspace(0, 220, w)[None, :, None] + np.linspace(0, 30, h)[:, None, None]
    return np.clip(ramp + rng.normal(0, 4, (h, w, 3)), 0, 255).astype(np.uint8)


def test_jpeg_roundtrip_is_read_only_and_remembers_its_bytes():
    img = _image()
    out = jpeg.roundtrip(img)
    assert out.shape == img.shape and out.dtype == np.uint8 and not out.flags.writeable
    assert np.abs(out.astype(int) - img).mean() < 8
    data = jpeg.jpeg_of(out)
    assert data is not None and np.array_equal(jpeg.decode(data), out)
    assert jpeg.jpeg_of(out.copy()) is None


def test_jpeg_decodes_like_pillow():
    data = jpeg.encode(_image(480, 640))
    assert np.array_equal(jpeg.decode(data), np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))


def test_jpeg_rejects_non_rgb():
    with pytest.raises(ValueError):
        jpeg.encode(np.zeros((4, 4), np.uint8))


# -------------------------------------------------------------------------------------------- language
def test_language_orders_inputs():
    lang = AgentLanguage()
    assert lang.check("get_commands") is not None
    for topic in ("seed", "episode_start", "observations", "get_commands", "episode_start", "get_commands"):
        assert lang.check(topic) is None, topic
        lang.push(topic)
    assert lang.check("seed") is not None
    lang = AgentLanguage()
    lang.push("seed")
    assert lang.check("seed") is not None and lang.check("observations") is not None


def test_stream_decodes_ahead_but_consumes_in_order():
    """Maps after the first in one buffer are decoded in the same pass; ``pending`` still counts them until
    they are handed out, and a garbage item after good ones is raised only when its turn comes."""
    good = [bytes.fromhex(UNDERSTOOD), bytes.fromhex(COMMANDS), bytes.fromhex(OVER)] * 5
    stream = wire.CborStream()
    stream.feed(b"".join(good) + b"\xa1\x61a\xf8\x10")
    for k, raw in enumerate(good):
        assert stream.pending == sum(map(len, good[k:])) + 5
        assert cbor2.dumps(stream.next()) == raw
    with pytest.raises(wire.GarbageError, match="simple value"):
        stream.next()
