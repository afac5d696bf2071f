"""Writers that write files: every output goes through one atomic writer
(:func:`bench.core.outputs.atomic_write`) that refuses device nodes, FIFOs, sockets and folders,
refuses an existing file without ``--force``, creates no folder unasked, and turns a full disk or
an I/O error into one line and exit 1 with nothing half-written."""

from __future__ import annotations

import errno
import os
import shutil
import socket
import stat
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.core.errors import InputError
from bench.core.outputs import WriteFailed, atomic_write, check_target, replacing
from bench.core.records import BSDFRecord
from bench.io import record_to_csv, save_figure
from bench.store import RunStore
from helpers.cli import run_main

IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def _record() -> BSDFRecord:
    """A small gonio record (2 wavelengths x 3 viewing directions), a few kB as CSV."""
    rows = [{"wavelength_nm": w, "theta_i": 30.0, "phi_i": 0.0, "theta_r": tr, "phi_r": 180.0, "hemisphere": "R",
             "value": 0.2 + 0.001 * tr, "std": 0.002} for w in (450.0, 550.0) for tr in (0.0, 20.0, 40.0)]
    return BSDFRecord(pd.DataFrame(rows), {"specimen": "lambert:albedo=0.8", "quantity": "BSDF", "seed": 1})


@pytest.fixture
def stored(tmp_path):
    """A store with one completed run of the record above; returns (store path, run id)."""
    path = tmp_path / "runs.sqlite"
    with RunStore(path) as s:
        rid = s.create_run("virtual", n_planned=1)
        s.add_record(rid, _record())
        s.set_status(rid, "completed")
    return path, rid


def _nodes(tmp_path: Path) -> dict[str, Path]:
    """Non-regular files the test creates itself: a FIFO, a socket, a folder, and (as root) a
    character device with /dev/full's numbers and a block device."""
    out = {"fifo": tmp_path / "fifo", "folder": tmp_path / "folder", "socket": tmp_path / "sock"}
    os.mkfifo(out["fifo"])
    out["folder"].mkdir()
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(out["socket"]))
    s.close()
    if IS_ROOT:
        out["char device"] = tmp_path / "full"
        os.mknod(out["char device"], 0o666 | stat.S_IFCHR, os.makedev(1, 7))  # /dev/full
    return out


def _only_files(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir())


# --- the writer itself ---------------------------------------------------------------------------


def test_non_regular_targets_are_refused_and_left_alone(tmp_path):
    nodes = _nodes(tmp_path)  # the character device only as root (mknod)
    before = {k: os.stat(p).st_mode for k, p in nodes.items()}
    for kind, path in nodes.items():
        for force in (False, True):
            with pytest.raises(InputError) as e:
                atomic_write(path, lambda tmp: Path(tmp).write_text("x"), force=force)
            msg = str(e.value)
            assert "\n" not in msg and str(path) in msg and "not a regular file" in msg
            assert kind.split()[0] in msg or kind == "folder" and "a folder" in msg
    assert {k: os.stat(p).st_mode for k, p in nodes.items()} == before  # nothing replaced
    assert _only_files(tmp_path) == sorted(p.name for p in nodes.values())  # no temporary file left


def test_fifo_refused_without_root(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is a FIFO, not a regular file"):
        record_to_csv(_record(), fifo)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and _only_files(tmp_path) == ["fifo"]


def test_existing_file_replaced_only_when_allowed(tmp_path):
    target = tmp_path / "r.csv"
    target.write_text("old\n")
    with replacing(False):
        with pytest.raises(InputError, match=r"exists: pass --force to replace it"):
            record_to_csv(_record(), target)
        assert target.read_text() == "old\n" and not Path(f"{target}.json").exists()
    with replacing(True):
        record_to_csv(_record(), target)
    assert target.read_text().startswith("wavelength_nm,")
    record_to_csv(_record(), target)  # the Python API replaces by default
    assert len(pd.read_csv(target)) == 6


def test_a_missing_folder_is_refused_not_created(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        atomic_write(tmp_path / "no" / "such" / "r.csv", lambda tmp: Path(tmp).write_text("x"))
    assert _only_files(tmp_path) == []


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO])
def test_medium_errors_become_write_failed_with_nothing_left(tmp_path, monkeypatch, code):
    target = tmp_path / "r.csv"
    target.write_text("old\n")

    def fsync(fd):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(WriteFailed) as e:
        record_to_csv(_record(), target)
    assert os.strerror(code) in str(e.value) and "nothing was written" in str(e.value)
    assert target.read_text() == "old\n" and _only_files(tmp_path) == ["r.csv"]


def test_figures_go_through_the_writer(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    fifo = tmp_path / "p.png"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="FIFO"):
        save_figure(fig, fifo)
    out = save_figure(fig, tmp_path / "q.svg")
    plt.close(fig)
    assert out.read_text().lstrip().startswith("<?xml") and _only_files(tmp_path) == ["p.png", "q.svg"]


# --- through the CLI -----------------------------------------------------------------------------


def test_export_to_a_device_fifo_or_folder_is_one_line_exit_2(tmp_path, stored, capsys):
    store, rid = stored
    for kind, path in _nodes(tmp_path).items():
        before = os.stat(path).st_mode
        for extra in ((), ("--force",)):
            code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", path, "--format", "csv", *extra)
            assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, (kind, err)
            assert ("is a folder" if kind == "folder" else "not a regular file") in err and str(path) in err
        assert os.stat(path).st_mode == before and not Path(f"{path}.json").exists()
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_export_refuses_existing_files_and_missing_folders(tmp_path, stored, capsys):
    store, rid = stored
    target = tmp_path / "r.parquet"
    target.write_bytes(b"old")
    code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", target)
    assert code == 2 and "exists: pass --force" in err and target.read_bytes() == b"old"
    code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", target, "--force")
    assert code == 0 and pd.read_parquet(target).shape[0] == 6
    # the sidecar of a CSV counts too: an existing r.csv.json refuses r.csv before anything is written
    (tmp_path / "r.csv.json").write_text("{}")
    code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", tmp_path / "r.csv")
    assert code == 2 and "r.csv.json exists" in err and not (tmp_path / "r.csv").exists()
    code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", tmp_path / "nodir" / "r.csv")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "does not exist" in err
    assert not (tmp_path / "nodir").exists()


def test_export_on_a_full_disk_is_one_line_exit_1(tmp_path, stored, capsys, monkeypatch):
    store, rid = stored
    real_fsync = os.fsync

    def fsync(fd):  # the store's own fsyncs are left alone; the export's temporary file is full
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".tmp"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc/self/fd to tell the export's file from the store's")
    monkeypatch.setattr(os, "fsync", fsync)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", out_dir / "r.csv")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "No space left on device" in err, err
    assert list(out_dir.iterdir()) == []  # neither the CSV, nor its sidecar, nor a temporary file


def _small_tmpfs(where: Path) -> bool:
    """Mount a 256 kB tmpfs at ``where`` (root with a working ``mount``), else False."""
    if not IS_ROOT or shutil.which("mount") is None:
        return False
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(where)], capture_output=True)
    return r.returncode == 0


def test_export_on_a_really_full_filesystem(tmp_path, stored, capsys):
    store, rid = stored
    mnt = tmp_path / "small"
    if not _small_tmpfs(mnt):
        pytest.skip("mounting a small tmpfs needs root and a working mount(8) (e.g. not in an unprivileged container)")
    try:
        with open(mnt / "filler", "wb", buffering=0) as f:  # fill it to the last byte
            try:
                while True:
                    f.write(b"\0" * 4096)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
        code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", mnt / "r.csv")
        assert code == 1 and len(err.strip().splitlines()) == 1 and "No space left on device" in err, err
        assert sorted(p.name for p in mnt.iterdir()) == ["filler"]
        (mnt / "filler").unlink()  # room again: the same command now writes both files
        code, out, err = run_main(capsys, "export", rid, "--store", store, "--out", mnt / "r.csv")
        assert code == 0 and len(pd.read_csv(mnt / "r.csv")) == 6 and (mnt / "r.csv.json").is_file()
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_spectro_csv_and_plot_refuse_nodes_before_measuring(tmp_path, capsys):
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    code, out, err = run_main(capsys, "spectro", "--specimen", "lambert:reflectance=0.5", "--wavelengths", "550",
                              "--rays", "1000", "--seed", "1", "--csv", fifo)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "is a FIFO" in err
    existing = tmp_path / "p.png"
    existing.write_bytes(b"old")
    code, out, err = run_main(capsys, "spectro", "--specimen", "lambert:reflectance=0.5", "--wavelengths", "550",
                              "--rays", "1000", "--seed", "1", "--plot", existing)
    assert code == 2 and "exists: pass --force" in err and existing.read_bytes() == b"old"
    assert out == ""  # refused before anything was measured or printed


def test_white_reference_file_goes_through_the_writer(tmp_path):
    from bench.core.roles import Reading
    from bench.io.white import WhiteReference, write_white_reference

    w = Reading(wavelengths=np.array([450.0, 550.0]), signal=np.array([1000.0, 1100.0]), integration_s=0.1,
                averages=1, timestamp=0.0, saturated=np.zeros(2, bool))
    ref = WhiteReference(w, None, "2026-12-06T00:00:00Z", "note", {"reflectance_factor": 0.99}, "b")
    fifo = tmp_path / "white.csv"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="FIFO"):
        write_white_reference(fifo, ref)
    with replacing(False):
        out = write_white_reference(tmp_path / "w.csv", ref)
        with pytest.raises(InputError, match="exists"):
            write_white_reference(out, ref)


def test_check_target_names_the_kind():
    assert check_target("/tmp/goniobench-no-such-file.csv") == Path("/tmp/goniobench-no-such-file.csv")
    if Path("/dev/full").exists():
        with pytest.raises(InputError, match="/dev/full is a character device, not a regular file"):
            check_target("/dev/full", force=True)


def test_gonio_csv_sidecar_is_checked_before_measuring(tmp_path, capsys):
    (tmp_path / "g.csv.json").write_text("{}")
    code, out, err = run_main(capsys, "gonio", "--specimen", "lambert:albedo=0.5", "--rays", "1000", "--seed", "1",
                              "--csv", tmp_path / "g.csv")
    assert code == 2 and out == "" and "g.csv.json exists: pass --force" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.csv.json"]


def test_a_sidecar_that_cannot_be_written_takes_its_new_csv_with_it(tmp_path, monkeypatch):
    real_fsync = os.fsync

    def fsync(fd):  # the disk fills up between the CSV and its sidecar
        if ".json." in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc/self/fd to tell the sidecar's file from the CSV's")
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(WriteFailed, match="r.csv.json"):
        record_to_csv(_record(), tmp_path / "r.csv")
    assert _only_files(tmp_path) == []


def test_a_file_that_appears_while_writing_is_not_replaced_without_force(tmp_path):
    target = tmp_path / "r.csv"

    def write(tmp):  # another process creates the target while this export is being written
        Path(tmp).write_text("ours\n")
        target.write_text("theirs\n")

    with replacing(False):
        with pytest.raises(InputError, match="exists: pass --force"):
            atomic_write(target, write)
    assert target.read_text() == "theirs\n" and _only_files(tmp_path) == ["r.csv"]
    with replacing(False):
        atomic_write(tmp_path / "new.csv", lambda tmp: Path(tmp).write_text("new\n"))
    assert (tmp_path / "new.csv").read_text() == "new\n" and _only_files(tmp_path) == ["new.csv", "r.csv"]
    assert oct((tmp_path / "new.csv").stat().st_mode & 0o777) != oct(0o600)  # a plain file's mode, not mkstemp's


def test_white_out_refuses_nodes_and_existing_files_before_any_work(tmp_path, capsys):
    fifo = tmp_path / "w.csv"
    os.mkfifo(fifo)
    missing = tmp_path / "none.sqlite"  # never opened: the output is refused first
    code, out, err = run_main(capsys, "white", "--from-run", "20261206-0000-abcd", "--store", missing, "--out", fifo)
    assert code == 2 and "is a FIFO, not a regular file" in err and len(err.strip().splitlines()) == 1
    old = tmp_path / "old.csv"
    old.write_text("# goniobench-white 1\n")
    code, out, err = run_main(capsys, "white", "--from-run", "20261206-0000-abcd", "--store", missing, "--out", old)
    assert code == 2 and "exists: pass --force" in err and old.read_text() == "# goniobench-white 1\n"
    code, out, err = run_main(capsys, "white", "--from-run", "20261206-0000-abcd", "--store", missing, "--out", old,
                              "--force")
    assert code == 2 and "exists" not in err and not missing.exists()  # past the output check: the store is missing
