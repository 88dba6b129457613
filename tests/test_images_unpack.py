"""Container images unpacked into a cached root file system (evaluator/images.py): the three forms, every
compression, the layer semantics (whiteouts, links), the cache, and hostile images that are refused with their
reason before anything of them is written."""

from __future__ import annotations

import os
import stat
import subprocess
import tarfile
from pathlib import Path

import pytest

from proxybench.evaluator.images import ImageError, ImageLimits, unpack_image
from support.images import member, oci_layout, require_image_tools, tar_layer

pytestmark = pytest.mark.usefixtures("_tools")

CONFIG = {"Entrypoint": ["/bin/agent"], "Cmd": ["--fast"], "Env": ["A=1"], "WorkingDir": "/work", "User": "7:8",
          "Labels": {"org.proxybench.agent.protocol": "aido-z2"}}


@pytest.fixture
def _tools() -> None:
    require_image_tools()


def _good_layers() -> list[bytes]:
    base = tar_layer([member("bin/", tarfile.DIRTYPE, mode=0o755),
                      member("bin/agent", data=b"#!/bin/sh\n", mode=0o4777),  # set-uid and world-writable
                      member("etc/", tarfile.DIRTYPE), member("etc/gone", data=b"x"),
                      member("opt/", tarfile.DIRTYPE), member("opt/old", data=b"old"),
                      member("usr/", tarfile.DIRTYPE), member("usr/lib/", tarfile.DIRTYPE),
                      member("lib", tarfile.SYMTYPE, linkname="usr/lib"),
                      member("abs", tarfile.SYMTYPE, linkname="/etc"),  # absolute: resolved in the image, not here
                      member("tmp", tarfile.SYMTYPE, linkname="/var/tmp")])  # a mount point the sandbox needs
    top = tar_layer([member("etc/.wh.gone"), member("opt/.wh..wh..opq"), member("opt/new", data=b"new"),
                     member("usr/lib/data", data=b"payload"), member("work/", tarfile.DIRTYPE),
                     member("work/hard", tarfile.LNKTYPE, linkname="usr/lib/data")])
    return [base, top]


@pytest.mark.parametrize("compression", ["none", "gzip", "zstd"])
def test_a_layout_unpacks_in_order_with_whiteouts_links_and_safe_modes(tmp_path: Path, compression: str) -> None:
    layout = oci_layout(tmp_path / "img", _good_layers(), CONFIG, compression=compression)
    image = unpack_image(layout, tmp_path / "cache")
    root = image.rootfs
    assert root.parent == tmp_path / "cache" / "rootfs" and root.name == image.digest[7:]
    assert not (root / "etc" / "gone").exists()  # whiteout
    assert sorted(os.listdir(root / "opt")) == ["new"]  # opaque whiteout, this layer's file kept
    assert os.readlink(root / "lib") == "usr/lib" and os.readlink(root / "abs") == "/etc"
    assert (root / "work" / "hard").read_bytes() == b"payload"
    assert os.stat(root / "work" / "hard").st_ino == os.stat(root / "usr" / "lib" / "data").st_ino
    mode = os.stat(root / "bin" / "agent").st_mode
    assert stat.S_IMODE(mode) == 0o755  # no set-uid, no group/other write
    for name in ("proc", "dev", "tmp", "scratch", "fifo"):
        assert (root / name).is_dir() and not (root / name).is_symlink()
    assert image.config.argv == ["/bin/agent", "--fast"] and image.config.working_dir == "/work"
    assert image.config.user == "7:8" and image.config.labels == CONFIG["Labels"]


def test_archives_of_both_kinds_unpack_to_the_same_tree_and_the_cache_answers_the_second_time(tmp_path: Path) -> None:
    layout = oci_layout(tmp_path / "img", _good_layers(), CONFIG)
    oci_tar, docker_tar = tmp_path / "oci.tar", tmp_path / "docker.tar"
    for ref in (f"oci-archive:{oci_tar}", f"docker-archive:{docker_tar}:agent:latest"):
        subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest", ref], check=True)
    cache = tmp_path / "cache"
    first = unpack_image(layout, cache)
    assert unpack_image(oci_tar, cache) == first  # the same manifest: the cached tree
    docker = unpack_image(docker_tar, cache)
    assert (docker.rootfs / "usr" / "lib" / "data").read_bytes() == b"payload"
    assert docker.config.argv == first.config.argv
    stamp = os.stat(docker.rootfs).st_mtime_ns
    assert unpack_image(docker_tar, cache) == docker and os.stat(docker.rootfs).st_mtime_ns == stamp
    assert os.listdir(cache / "staging") == []


def _hostile(tmp_path: Path, outside: Path) -> dict[str, tuple[list[bytes], str]]:
    """name → (layers, what the refusal says)."""
    escape = [tar_layer([member("escape", tarfile.SYMTYPE, linkname=str(outside))]),
              tar_layer([member("escape/pwned", data=b"owned")])]
    return {
        "symlink-escape": (escape, "written through the symbolic link 'escape'"),
        "symlink-escape-same-layer": ([tar_layer([member("e", tarfile.SYMTYPE, linkname="../../.."),
                                                  member("e/x/pwned", data=b"owned")])], "symbolic link 'e'"),
        "dotdot-member": ([tar_layer([member("../pwned", data=b"owned")])], "'..' component"),
        "dotdot-deep": ([tar_layer([member("a/../../pwned", data=b"owned")])], "'..' component"),
        "whiteout-of-root": ([tar_layer([member(".wh..")])], "whiteout of '.'"),
        "whiteout-of-parent": ([tar_layer([member("a/.wh...")])], "whiteout of '..'"),
        "hardlink-out": ([tar_layer([member("h", tarfile.LNKTYPE, linkname="../../etc/shadow")])], "'..' component"),
        "hardlink-through-symlink": ([tar_layer([member("s", tarfile.SYMTYPE, linkname="/etc"),
                                                 member("h", tarfile.LNKTYPE, linkname="s/shadow")])],
                                     "symbolic link 's'"),
        "device": ([tar_layer([member("dev/sda", tarfile.BLKTYPE)])], "device files"),
        "root-as-file": ([tar_layer([member("./", data=b"x")])], "only a folder can stand for the root"),
    }


@pytest.mark.parametrize("case", list(_hostile(Path("/"), Path("/"))))
def test_hostile_layers_are_refused_naming_layer_and_member_and_write_nothing(tmp_path: Path, case: str) -> None:
    outside = tmp_path / "outside"
    outside.mkdir()
    layers, reason = _hostile(tmp_path, outside)[case]
    layout = oci_layout(tmp_path / "img", layers, CONFIG)
    cache = tmp_path / "cache"
    with pytest.raises(ImageError, match=r"layer [01] \(sha256:") as err:
        unpack_image(layout, cache)
    assert reason in str(err.value) and "\n" not in str(err.value)
    _nothing_written(cache, outside)


def _nothing_written(cache: Path, outside: Path) -> None:
    assert os.listdir(outside) == []
    assert os.listdir(cache / "rootfs") == [] and os.listdir(cache / "staging") == []


def test_digest_size_and_diff_id_mismatches_are_refused(tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    outside.mkdir()
    layer = tar_layer([member("f", data=b"hello")])
    cases = {}
    flipped = oci_layout(tmp_path / "flipped", [layer], CONFIG, compression="none")
    blob = next(p for p in (flipped / "blobs" / "sha256").iterdir() if p.stat().st_size == len(layer))
    blob.write_bytes(layer.replace(b"hello", b"HELLO"))  # same size, other bytes
    cases[flipped] = "Digest did not match|hash to sha256:"  # skopeo's check, or ours
    grown = oci_layout(tmp_path / "grown", [layer], CONFIG, compression="none")
    blob = next(p for p in (grown / "blobs" / "sha256").iterdir() if p.stat().st_size == len(layer))
    blob.write_bytes(layer + b"\0" * 512)
    cases[grown] = "Digest did not match|not the descriptor's"
    cases[oci_layout(tmp_path / "diffid", [layer], CONFIG, diff_ids=["sha256:" + "0" * 64])] = "diff_id"
    for layout, reason in cases.items():
        with pytest.raises(ImageError, match=reason) as err:
            unpack_image(layout, tmp_path / "cache")
        assert "\n" not in str(err.value)
        _nothing_written(tmp_path / "cache", outside)


def test_members_bytes_and_layers_are_bounded(tmp_path: Path) -> None:
    many = tar_layer([member(f"f{i}") for i in range(1200)])  # a stand-in for a 10^6-file layer
    with pytest.raises(ImageError, match="more than 1000 members"):
        unpack_image(oci_layout(tmp_path / "many", [many], CONFIG), tmp_path / "c",
                     limits=ImageLimits(max_members=1000))
    big = tar_layer([member("big", data=b"\0" * (2 << 20))])  # 2 MiB of zeros: a few KiB gzipped
    with pytest.raises(ImageError, match="more than 1048576 bytes"):
        unpack_image(oci_layout(tmp_path / "big", [big], CONFIG), tmp_path / "c", limits=ImageLimits(max_bytes=1 << 20))
    layers = [tar_layer([member(f"l{i}")]) for i in range(5)]
    with pytest.raises(ImageError, match="5 layers; at most 4"):
        unpack_image(oci_layout(tmp_path / "deep", layers, CONFIG), tmp_path / "c", limits=ImageLimits(max_layers=4))
    assert os.listdir(tmp_path / "c" / "rootfs") == []


def test_not_an_image_is_a_one_line_error(tmp_path: Path) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "x.tar").write_bytes(b"not a tar at all" * 100)
    for path, reason in ((tmp_path / "folder", "not an OCI image layout"), (tmp_path / "x.tar", "not a tar"),
                         (tmp_path / "missing", "no such file or folder")):
        with pytest.raises(ImageError, match=reason):
            unpack_image(path, tmp_path / "cache")


def test_the_time_limit_bounds_the_whole_unpack(tmp_path: Path) -> None:
    layout = oci_layout(tmp_path / "img", _good_layers(), CONFIG)
    with pytest.raises(ImageError, match="time limit"):
        unpack_image(layout, tmp_path / "cache", limits=ImageLimits(max_seconds=0.001))
    assert os.listdir(tmp_path / "cache" / "rootfs") == [] and os.listdir(tmp_path / "cache" / "staging") == []


def test_a_cached_digest_is_not_enough_the_folder_must_hold_its_bytes(tmp_path: Path) -> None:
    import shutil

    cache = tmp_path / "cache"
    layout = oci_layout(tmp_path / "img", _good_layers(), CONFIG, compression="none")
    unpack_image(layout, cache)
    copy = tmp_path / "copy"  # the same index (the cached digest), other layer bytes of the same size
    shutil.copytree(layout, copy)
    blob = max((copy / "blobs" / "sha256").iterdir(), key=lambda p: p.stat().st_size)
    data = bytearray(blob.read_bytes())
    data[-2000] ^= 0xFF
    blob.write_bytes(bytes(data))
    with pytest.raises(ImageError, match=r"Digest did not match|hash to"):
        unpack_image(copy, cache)
    blob.unlink()
    blob.symlink_to("/etc/shadow")
    with pytest.raises(ImageError, match="is not a plain file"):
        unpack_image(copy, cache)


def test_a_compressed_archive_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    import gzip

    layout = oci_layout(tmp_path / "img", _good_layers(), CONFIG)
    archive = tmp_path / "docker.tar"
    subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest",
                    f"docker-archive:{archive}:a:latest"], check=True)
    gz = tmp_path / "docker.tar.gz"
    gz.write_bytes(gzip.compress(archive.read_bytes(), compresslevel=1))
    with pytest.raises(ImageError, match="a compressed archive; give the tar itself"):
        unpack_image(gz, tmp_path / "cache")
    assert os.listdir(tmp_path / "cache" / "staging") == []
