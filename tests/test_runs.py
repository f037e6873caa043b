"""Run directories under kills, damage, races, full disks and other code: nothing lost, nothing
silently wrong.  Every interrupted or damaged run must end exactly as the uninterrupted
`quick` sweep (``finished_quick``) did."""

import dataclasses
import errno
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from mjxcpg.cli import main
from mjxcpg.training import checkpoints, config, provenance, runs

SWEEP = ["sweep", "--config", "quick", "--quiet", "--engine", "native", "--checkpoint-every", "0"]
RESULTS = ("summary.json", "returns.json")


def one_line_error(err: str) -> str:
    """The last line of stderr, checked to be the CLI's one-line error."""
    last = err.strip().splitlines()[-1]
    assert last.startswith("mjxcpg: error:")
    return last


def assert_same_results(run: Path, reference: Path) -> None:
    for name in RESULTS:
        assert (run / name).read_bytes() == (reference / name).read_bytes(), name


def unfinished_copy(finished: Path, into: Path) -> Path:
    """A copy of a finished run as it was after its last checkpoint, before its report."""
    run = into / "run"
    shutil.copytree(finished, run)
    for name in ("summary.json", "returns.json", "table1.md", "stats.json"):
        (run / name).unlink()
    return run


def checkpoint_steps(run: Path) -> list[int]:
    return sorted(int(p.name) for p in (run / checkpoints.CHECKPOINTS).iterdir() if p.name.isdigit())


def tear(step_dir: Path) -> None:
    """A write cut short: every file of the checkpoint loses its second half."""
    for f in step_dir.rglob("*"):
        if f.is_file() and f.stat().st_size > 1:
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])


def corrupt(step_dir: Path) -> None:
    """Bits rotted on disk: the largest data file keeps its size, its bytes change."""
    data = max((f for f in step_dir.rglob("*") if f.is_file()), key=lambda f: f.stat().st_size)
    raw = bytearray(data.read_bytes())
    for i in range(0, len(raw), 7):
        raw[i] ^= 0xFF
    data.write_bytes(bytes(raw))


def tree_bytes(root: Path) -> dict:
    """Every file under ``root`` but the lock, by path: what a run holds."""
    return {p.relative_to(root): p.read_bytes() for p in root.rglob("*")
            if p.is_file() and p.name != runs.LOCK_NAME}


def test_checkpoint_interval_writes_the_end_and_changes_no_result(finished_quick, tmp_path):
    """Checkpoints after every chunk (``finished_quick``) and only at the end (an interval
    longer than the run): one checkpoint, holding the state the run ended with (the last of
    every chunk's), and the same results byte for byte."""
    run = tmp_path / "run"
    only_at_the_end = SWEEP[:SWEEP.index("--checkpoint-every")] + ["--checkpoint-every", "1e6"]
    assert main(only_at_the_end + ["--out", str(run), "--no-tensorboard"]) == 0
    assert checkpoint_steps(run) == [1] and checkpoint_steps(finished_quick)[-1] > 1
    ends, every_chunk = checkpoints.newest_intact(checkpoints.manager_of(run)), \
        checkpoints.newest_intact(checkpoints.manager_of(finished_quick))
    assert ends[1].keys() == every_chunk[1].keys()
    for key in ends[1]:
        np.testing.assert_array_equal(ends[1][key], every_chunk[1][key], err_msg=key)
    assert_same_results(run, finished_quick)


# ---------------------------------------------------------------- damaged checkpoints

def test_torn_latest_checkpoint_falls_back_and_ends_as_uninterrupted(finished_quick, tmp_path, capsys):
    run = unfinished_copy(finished_quick, tmp_path)
    newest, previous = checkpoint_steps(run)[-1], checkpoint_steps(run)[-2]
    tear(run / checkpoints.CHECKPOINTS / str(newest))
    assert main(SWEEP + ["--out", str(run), "--resume"]) == 0
    notices = [line for line in capsys.readouterr().err.splitlines() if "damaged" in line]
    assert len(notices) == 1
    assert f"checkpoint {newest} is damaged" in notices[0] and f"using checkpoint {previous}" in notices[0]
    assert (run / checkpoints.DAMAGED_CHECKPOINTS / str(newest)).is_dir()  # kept, out of the way
    assert_same_results(run, finished_quick)


def fingerprint_by_hand(data: dict) -> np.ndarray:
    return np.frombuffer(hashlib.sha256(json.dumps(data, sort_keys=True).encode()).digest(), np.uint8)


REFLEX_KEYS = ("h_heading", "max_turn", "slope_reflex_s", "max_ankle_pitch")
POSTURE_KEYS = ("slope_posture",)


def test_run_recorded_before_a_key_was_added_resumes_and_loads(finished_quick, tmp_path):
    """A run whose config.json was written before ``learner.unit_slope``, ``platform``,
    ``learner.fall_impulse``, ``learner.mean_step_sigma_power``, the controller's reflex keys,
    its slope posture, ``k_e``, the heading command, the hand-designed start's fade and the
    stepping output existed (all absent; their old behaviour False, QRIO, False, 0, reflexes off,
    the robot tilted with the floor, no energy term, heading 0, no fade, one policy output):
    resumed, it ends as the uninterrupted run; and checkpoints fingerprinted without the
    newest keys, back to all of them, are accepted, the fingerprints built here by hand."""
    run = unfinished_copy(finished_quick, tmp_path)
    record = json.loads((run / "config.json").read_text())
    del record["spec"]["learner"]["unit_slope"], record["spec"]["platform"], record["spec"]["learner"]["fall_impulse"]
    del record["spec"]["learner"]["mean_step_sigma_power"], record["spec"]["k_e"]
    del record["spec"]["learner"]["stepping_a_max"]
    for key in REFLEX_KEYS + POSTURE_KEYS + ("heading_command", "hand_fade_seconds"):
        del record["spec"]["controller"][key]
    (run / "config.json").write_text(json.dumps(record))
    assert main(SWEEP + ["--out", str(run), "--resume"]) == 0
    assert_same_results(run, finished_quick)
    spec = config.load_spec("quick")
    before_stepping = config.spec_to_dict(spec)
    del before_stepping["learner"]["stepping_a_max"]
    before_fade = json.loads(json.dumps(before_stepping))
    del before_fade["controller"]["hand_fade_seconds"]
    before_command = json.loads(json.dumps(before_fade))
    del before_command["controller"]["heading_command"]
    before_energy = json.loads(json.dumps(before_command))
    del before_energy["k_e"]
    before_posture = json.loads(json.dumps(before_energy))
    for key in POSTURE_KEYS:
        del before_posture["controller"][key]
    before_reflexes = json.loads(json.dumps(before_posture))
    for key in REFLEX_KEYS:
        del before_reflexes["controller"][key]
    before_power = json.loads(json.dumps(before_reflexes))
    del before_power["learner"]["mean_step_sigma_power"]
    before_impulse = json.loads(json.dumps(before_power))
    del before_impulse["learner"]["fall_impulse"]
    before_platform = json.loads(json.dumps(before_impulse))
    del before_platform["platform"]
    before_all = json.loads(json.dumps(before_platform))
    del before_all["learner"]["unit_slope"]
    accepted = checkpoints._accepted_fingerprints(spec)
    for old in (before_stepping, before_fade, before_command, before_energy, before_posture, before_reflexes, before_power, before_impulse, before_platform, before_all):
        assert any(np.array_equal(fingerprint_by_hand(old), f) for f in accepted)
    with_slope = dataclasses.replace(spec, learner=dataclasses.replace(spec.learner, unit_slope=True))
    slope_true = {"unit_slope": True}
    assert config.earlier_spec_dicts(with_slope) == [   # not before unit_slope
        before_stepping | {"learner": before_stepping["learner"] | slope_true}, before_fade | {"learner": before_fade["learner"] | slope_true}, before_command | {"learner": before_command["learner"] | slope_true},
        before_energy | {"learner": before_energy["learner"] | slope_true},
        before_posture | {"learner": before_posture["learner"] | slope_true},
        before_reflexes | {"learner": before_reflexes["learner"] | slope_true},
        before_power | {"learner": before_power["learner"] | slope_true},
        before_impulse | {"learner": before_impulse["learner"] | slope_true},
        before_platform | {"learner": before_platform["learner"] | slope_true}]
    assert config.earlier_spec_dicts(dataclasses.replace(spec, platform="child")) == [
        before_stepping | {"platform": "child"}, before_fade | {"platform": "child"}, before_command | {"platform": "child"}, before_energy | {"platform": "child"}, before_posture | {"platform": "child"}, before_reflexes | {"platform": "child"}, before_power | {"platform": "child"},
        before_impulse | {"platform": "child"}]   # not before platform
    impulse = dataclasses.replace(spec, learner=dataclasses.replace(spec.learner, fall_impulse=True))
    impulse_true = {"fall_impulse": True}
    assert config.earlier_spec_dicts(impulse) == [before_stepping | {"learner": before_stepping["learner"] | impulse_true}, before_fade | {"learner": before_fade["learner"] | impulse_true}, before_command | {"learner": before_command["learner"] | impulse_true},
                                                  before_energy | {"learner": before_energy["learner"] | impulse_true},
                                                  before_posture | {"learner": before_posture["learner"] | impulse_true},
                                                  before_reflexes | {"learner": before_reflexes["learner"] | impulse_true},
                                                  before_power | {"learner": before_power["learner"] | impulse_true}]
    power = dataclasses.replace(spec, learner=dataclasses.replace(spec.learner, mean_step_sigma_power=2.0))
    assert config.earlier_spec_dicts(power) == [
        before_stepping | {"learner": before_stepping["learner"] | {"mean_step_sigma_power": 2.0}}, before_fade | {"learner": before_fade["learner"] | {"mean_step_sigma_power": 2.0}}, before_command | {"learner": before_command["learner"] | {"mean_step_sigma_power": 2.0}},
        before_energy | {"learner": before_energy["learner"] | {"mean_step_sigma_power": 2.0}},
        before_posture | {"learner": before_posture["learner"] | {"mean_step_sigma_power": 2.0}},
        before_reflexes | {"learner": before_reflexes["learner"] | {"mean_step_sigma_power": 2.0}}]
    heading = dataclasses.replace(spec, controller=dataclasses.replace(spec.controller, h_heading=0.6))
    assert config.earlier_spec_dicts(heading) == [  # not before the heading reflex
        before_stepping | {"controller": before_stepping["controller"] | {"h_heading": 0.6}}, before_fade | {"controller": before_fade["controller"] | {"h_heading": 0.6}}, before_command | {"controller": before_command["controller"] | {"h_heading": 0.6}},
        before_energy | {"controller": before_energy["controller"] | {"h_heading": 0.6}},
        before_posture | {"controller": before_posture["controller"] | {"h_heading": 0.6}}]
    posture = dataclasses.replace(spec, controller=dataclasses.replace(spec.controller, slope_posture=0.5))
    assert config.earlier_spec_dicts(posture) == [  # not before the slope posture
        before_stepping | {"controller": before_stepping["controller"] | {"slope_posture": 0.5}}, before_fade | {"controller": before_fade["controller"] | {"slope_posture": 0.5}}, before_command | {"controller": before_command["controller"] | {"slope_posture": 0.5}},
        before_energy | {"controller": before_energy["controller"] | {"slope_posture": 0.5}}]
    energy = dataclasses.replace(spec, k_e=(1.0,) * len(spec.k_s))
    assert config.earlier_spec_dicts(energy) == [  # not before the energy reward
        before_stepping | {"k_e": [1.0] * len(spec.k_s)}, before_fade | {"k_e": [1.0] * len(spec.k_s)}, before_command | {"k_e": [1.0] * len(spec.k_s)}]
    command = dataclasses.replace(spec, controller=dataclasses.replace(spec.controller, heading_command=0.2))
    assert config.earlier_spec_dicts(command) == [  # not before the heading command
        before_stepping | {"controller": before_stepping["controller"] | {"heading_command": 0.2}}, before_fade | {"controller": before_fade["controller"] | {"heading_command": 0.2}}]
    fade = dataclasses.replace(spec, controller=dataclasses.replace(spec.controller, hand_fade_seconds=2.0))
    assert config.earlier_spec_dicts(fade) == [  # not before the hand-designed start's fade
        before_stepping | {"controller": before_stepping["controller"] | {"hand_fade_seconds": 2.0}}]
    stepping = dataclasses.replace(spec, learner=dataclasses.replace(spec.learner, stepping_a_max=0.4))
    assert config.earlier_spec_dicts(stepping) == []  # not before the stepping output


def test_a_checkpoint_of_an_earlier_config_version_loads(finished_quick, monkeypatch):
    """A checkpoint fingerprinted as earlier code wrote its config (not the first fingerprint
    this code accepts) is restored; one that matches none is refused."""
    accepted = checkpoints._accepted_fingerprints
    other = np.zeros(32, np.uint8)  # a sha256 that no config has
    monkeypatch.setattr(checkpoints, "_accepted_fingerprints", lambda spec: [other, *accepted(spec)])
    runs.load_run(finished_quick)
    monkeypatch.setattr(checkpoints, "_accepted_fingerprints", lambda spec: [other, other])
    with pytest.raises(runs.RunError, match="another config"):
        runs.load_run(finished_quick)


def test_corrupted_checkpoint_is_caught_by_its_sha256(finished_quick, tmp_path):
    run = unfinished_copy(finished_quick, tmp_path)
    steps = checkpoint_steps(run)
    corrupt(run / checkpoints.CHECKPOINTS / str(steps[-1]))
    step, _, damaged = checkpoints.newest_intact(checkpoints.manager_of(run))
    assert step == steps[-2] and [d for d, _ in damaged] == [steps[-1]]


def test_no_intact_checkpoint_is_one_line_error_and_nothing_is_deleted(finished_quick, tmp_path, capsys):
    run = unfinished_copy(finished_quick, tmp_path)
    for step in checkpoint_steps(run):
        (tear if step % 2 else corrupt)(run / checkpoints.CHECKPOINTS / str(step))
    before = tree_bytes(run)
    assert main(SWEEP + ["--out", str(run), "--resume"]) == 2
    assert "no intact checkpoint" in one_line_error(capsys.readouterr().err)
    assert tree_bytes(run) == before


# ---------------------------------------------------------------- a full disk

def test_full_disk_keeps_the_previous_checkpoint_and_is_one_line_error(finished_quick, tmp_path, capsys,
                                                                       monkeypatch):
    """The disk fills while the third checkpoint is written: the writer gets ENOSPC, as orbax's
    metadata write would from the file system."""
    from orbax.checkpoint._src.path import async_path

    write_text = async_path.write_text

    async def full_from_step_3(path, text):
        if any(part.split(".")[0] == "3" for part in Path(path).parts[-3:]):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return await write_text(path, text)

    monkeypatch.setattr(async_path, "write_text", full_from_step_3)
    run = tmp_path / "run"
    assert main(SWEEP + ["--out", str(run)]) == 2
    assert "No space left on device" in one_line_error(capsys.readouterr().err)
    assert not runs.is_finished(run)
    step, _, damaged = checkpoints.newest_intact(checkpoints.manager_of(run))
    assert (step, damaged) == (2, [])
    monkeypatch.setattr(async_path, "write_text", write_text)
    assert main(SWEEP + ["--out", str(run), "--resume"]) == 0
    assert_same_results(run, finished_quick)


def test_a_failed_saves_closed_loop_callbacks_are_dropped_and_nothing_else(tmp_path, monkeypatch):
    """Once orbax writes checkpoints here, the "Event loop is closed" errors that a failed
    save's pending tensorstore callbacks raise (no object, from their own threads) are
    dropped; any other unraisable error reaches the hook there was before."""
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", seen.append)
    checkpoints.manager_at(tmp_path / "checkpoints", writer=True).close()

    def unraisable(error, owner=None):
        return types.SimpleNamespace(exc_type=type(error), exc_value=error, exc_traceback=None,
                                     err_msg=None, object=owner)

    closed = unraisable(RuntimeError("Event loop is closed"))
    others = [unraisable(RuntimeError("Event loop is closed"), owner=object()),
              unraisable(RuntimeError("something else")), unraisable(ValueError("Event loop is closed"))]
    for args in [closed, *others]:
        sys.unraisablehook(args)
    assert seen == others


# ---------------------------------------------------------------- the lock

def test_second_sweep_on_a_held_directory_is_refused_at_once(tmp_path, capsys):
    run = tmp_path / "run"
    with runs.locked(run):
        start = time.perf_counter()
        assert main(SWEEP + ["--out", str(run)]) == 2
        refused_in = time.perf_counter() - start
    err = one_line_error(capsys.readouterr().err)
    assert f"pid {os.getpid()} on {socket.gethostname()}" in err
    assert refused_in < 5.0  # before any simulation is built
    assert runs.run_files(run) == []


def test_lock_of_a_dead_process_is_taken_over(tmp_path, capsys):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    pid = int(dead.stdout)
    run = tmp_path / "run"
    run.mkdir()
    (run / runs.LOCK_NAME).write_text(json.dumps({"pid": pid, "host": socket.gethostname()}))
    with runs.locked(run):
        assert json.loads((run / runs.LOCK_NAME).read_text())["pid"] == os.getpid()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"took over the lock of pid {pid}" in err[0]
    assert (run / runs.LOCK_NAME).read_text() == ""  # released


# ---------------------------------------------------------------- the code that made a run

def test_code_identity_follows_sources_and_model(tmp_path):
    package = tmp_path / "mjxcpg"
    shutil.copytree(provenance.PACKAGE_DIR, package, ignore=shutil.ignore_patterns("__pycache__"))
    models = package / provenance.MODEL_DIR.relative_to(provenance.PACKAGE_DIR)
    same = provenance.code_identity(package, models)
    assert provenance.differences(same, provenance.code_identity()) == []
    assert provenance.differences(None, same) == ["the run has no record of its code"]
    learner = package / "learning" / "learner.py"
    learner.write_text(learner.read_text() + "\n# changed\n")
    assert [d.split()[0] for d in provenance.differences(same, provenance.code_identity(package, models))] \
        == ["source_sha256"]
    model = next(models.rglob("*.xml"))
    model.write_text(model.read_text().replace("<mujoco", "<mujoco ", 1))
    changed = provenance.code_identity(package, models)
    assert [d.split()[0] for d in provenance.differences(same, changed)] == ["source_sha256", "model_sha256"]


def test_resume_with_other_code_is_refused_unless_allowed_and_then_recorded(finished_quick, tmp_path, capsys):
    run = unfinished_copy(finished_quick, tmp_path)
    record = json.loads((run / "config.json").read_text())
    assert record["code"] == provenance.code_identity() | {"git_commit": record["code"]["git_commit"]}
    record["code"]["source_sha256"] = "0" * 64
    (run / "config.json").write_text(json.dumps(record))
    before = tree_bytes(run)
    assert main(SWEEP + ["--out", str(run), "--resume"]) == 2
    assert "--allow-other-code" in one_line_error(capsys.readouterr().err)
    assert tree_bytes(run) == before
    assert main(SWEEP + ["--out", str(run), "--resume", "--allow-other-code"]) == 0
    resumed = json.loads((run / "config.json").read_text())["resumed_with_other_code"]
    assert len(resumed) == 1 and resumed[0]["differences"][0].startswith("source_sha256 000000000000 -> ")
    assert resumed[0]["code"]["source_sha256"] == provenance.code_identity()["source_sha256"]
    assert_same_results(run, finished_quick)  # the code is in fact the same


def test_failed_resume_with_other_code_records_nothing(finished_quick, tmp_path, capsys):
    """Allowed other code, but no checkpoint to resume from: refused, and config.json says
    no resume happened."""
    run = unfinished_copy(finished_quick, tmp_path)
    record = json.loads((run / "config.json").read_text())
    record["code"]["source_sha256"] = "0" * 64
    (run / "config.json").write_text(json.dumps(record))
    for step in checkpoint_steps(run):
        tear(run / checkpoints.CHECKPOINTS / str(step))
    before = tree_bytes(run)
    assert main(SWEEP + ["--out", str(run), "--resume", "--allow-other-code"]) == 2
    assert "no intact checkpoint" in one_line_error(capsys.readouterr().err)
    assert tree_bytes(run) == before


def test_resume_on_another_engine_is_refused(finished_quick, tmp_path, capsys):
    """The run was made on the native engine: resuming it on MuJoCo C through Python (the
    same state layout) would leave config.json naming the wrong engine, and on MJX the state
    does not fit; both are refused before anything is read or written."""
    run = unfinished_copy(finished_quick, tmp_path)
    before = tree_bytes(run)
    for engine in ("mujoco", "mjx"):
        argv = ["sweep", "--config", "quick", "--quiet", "--engine", engine, "--out", str(run), "--resume"]
        assert main(argv) == 2
        assert "--engine native" in one_line_error(capsys.readouterr().err)
    assert tree_bytes(run) == before


def test_force_replaces_only_a_run_directory(tmp_path, capsys):
    """A mistyped --out that holds a user's files, not a run: --force deletes nothing, and
    without it the error does not suggest --force."""
    folder = tmp_path / "results"
    (folder / "thesis").mkdir(parents=True)
    (folder / "thesis" / "chapter.tex").write_text("months of work")
    (folder / "notes.txt").write_text("keep me")
    before = tree_bytes(folder)
    assert main(SWEEP + ["--out", str(folder), "--force"]) == 2
    assert "not a run directory" in one_line_error(capsys.readouterr().err)
    assert main(SWEEP + ["--out", str(folder)]) == 2
    error = one_line_error(capsys.readouterr().err)
    assert "not a run directory" in error and "--force" not in error
    assert tree_bytes(folder) == before


def test_finished_run_is_never_resumed_over(finished_quick, tmp_path, capsys):
    """``make run`` a second time: the finished run's Table 1 again, exit 0, no file changed;
    a finished run of another config is refused."""
    before = tree_bytes(finished_quick)
    assert main(SWEEP + ["--out", str(finished_quick), "--resume"]) == 0
    captured = capsys.readouterr()
    assert "finished run" in captured.err and "| k_s |" in captured.out
    assert tree_bytes(finished_quick) == before
    other = tmp_path / "other.toml"
    other.write_text((config.CONFIG_DIR / "quick.toml").read_text().replace("max_trials = 6", "max_trials = 7"))
    assert main(["sweep", "--config", str(other), "--quiet", "--out", str(finished_quick), "--resume"]) == 2
    assert "another config" in one_line_error(capsys.readouterr().err)
    assert tree_bytes(finished_quick) == before


# ---------------------------------------------------------------- kills

def _tmp_writes(run: Path) -> list[str]:
    """Checkpoints being written: orbax's temporary directories."""
    folder = run / checkpoints.CHECKPOINTS
    return [n for n in os.listdir(folder) if "tmp" in n] if folder.is_dir() else []


def _steps(run: Path) -> set[int]:
    folder = run / checkpoints.CHECKPOINTS
    return {int(n) for n in os.listdir(folder) if n.isdigit()} if folder.is_dir() else set()


def _lock_holder(run: Path) -> int | None:
    try:
        return json.loads((run / runs.LOCK_NAME).read_text())["pid"]
    except (OSError, ValueError, KeyError):
        return None


@pytest.mark.slow
def test_ten_kills_at_random_moments_end_as_the_uninterrupted_run(tmp_path, capsys):
    """A sweep of the `quick` config with short chunks (many checkpoints) is killed with
    SIGKILL ten times at seeded random moments, each followed by ``--resume``: a kill either
    waits for one of the next checkpoint writes to begin, or falls at a random time from the
    start (compilation included) but before the run could end.  While a killed run's successor holds the lock, a second
    sweep on its directory is refused.  The final results equal, byte for byte, those of the
    same config run without a kill."""
    spec = config.spec_to_dict(config.load_spec("quick")) | {"chunk_seconds": 0.5}
    path = tmp_path / "quick_short_chunks.json"
    path.write_text(json.dumps(spec))
    sweep = [sys.executable, "-m", "mjxcpg", "sweep", "--config", str(path), "--quiet", "--engine", "native",
             "--checkpoint-every", "0"]

    reference = tmp_path / "reference"
    start = time.perf_counter()
    subprocess.run(sweep + ["--out", str(reference)], check=True, capture_output=True)
    reference_seconds = time.perf_counter() - start
    kills_wanted, steps_per_life = 10, 3
    assert max(_steps(reference)) > kills_wanted * steps_per_life, "chunks too long: the run could end"

    rng = np.random.default_rng(18)
    run = tmp_path / "killed"
    kills, during_writes, races_refused, takeovers = 0, 0, 0, 0
    while kills < kills_wanted:
        err_path = tmp_path / f"stderr_{kills}.txt"
        with open(err_path, "w") as err:
            proc = subprocess.Popen(sweep + ["--out", str(run)] + (["--resume"] if kills else []),
                                    stdout=subprocess.DEVNULL, stderr=err)
        started, steps_before = time.perf_counter(), _steps(run)
        during_write = rng.random() < 0.5
        # From the first new checkpoint on, a temporary directory is this process's write
        # (orbax clears those a killed one left before it writes).
        wait_steps = int(rng.integers(1, steps_per_life))
        kill_after = rng.uniform(0, reference_seconds)
        raced = False
        while proc.poll() is None:
            new_steps = len(_steps(run) - steps_before)
            if not raced and _lock_holder(run) == proc.pid and new_steps >= 1:
                assert main(["sweep", "--config", str(path), "--out", str(run), "--quiet"]) == 2
                assert f"in use by pid {proc.pid}" in one_line_error(capsys.readouterr().err)
                races_refused, raced = races_refused + 1, True
            if during_write:
                due = new_steps >= wait_steps and _tmp_writes(run)
            else:
                # A random moment, but before the run could finish: at most 3 new checkpoints.
                due = time.perf_counter() - started >= kill_after or new_steps >= steps_per_life
            if due:
                proc.send_signal(signal.SIGKILL)
                break
            time.sleep(0.001)
        proc.wait()
        assert proc.returncode == -signal.SIGKILL, f"the run ended by itself: {err_path.read_text()}"
        kills += 1
        during_writes += new_steps >= 1 and bool(_tmp_writes(run))
        takeovers += "took over the lock" in err_path.read_text()
    final = subprocess.run(sweep + ["--out", str(run), "--resume"], capture_output=True, text=True)
    assert final.returncode == 0, final.stderr
    takeovers += "took over the lock" in final.stderr
    assert_same_results(run, reference)
    assert during_writes >= 1 and races_refused >= 1
    print(f"kills survived {kills}, of them during a checkpoint write {during_writes}; "
          f"races refused {races_refused}; stale locks taken over {takeovers}")
