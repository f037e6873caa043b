"""Headless rendering: a filmstrip PNG, an MP4 and a GIF when OpenGL is there, one line when not.

MuJoCo reads MUJOCO_GL once, at import, and this test process has imported it already, so
every rendering check runs in a fresh interpreter."""

import json
import os
import subprocess
import sys

import imageio_ffmpeg
import numpy as np
import pytest

from learned_run import make_learned_run
from mjxcpg.evaluation.render import headless_gl_backend, write_mp4

RENDER_SCRIPT = """
import json, sys
from pathlib import Path
import numpy as np
from mjxcpg.control.sim import standing_qpos
from mjxcpg.evaluation import render
from mjxcpg.physics.model import Layout, load_model

model = load_model()
qpos = np.stack([standing_qpos(model, Layout.of(model), x0, 0.215) for x0 in (0.0, 0.02, 0.04)])
out = Path(sys.argv[1])
try:
    frames = render.render_frames(model, qpos, render.View(width=64, height=48))
    render.write_mp4(frames, out / "gait.mp4", 0.04)
except render.RenderError as error:
    print(json.dumps({"error": str(error)}))
    raise SystemExit(0)
render.filmstrip(frames, np.array([0.0, 0.1, 0.2]), columns=2).save(out / "strip.png")
render.write_gif(frames, out / "gait.gif", 0.1)
print(json.dumps({"shape": list(frames.shape), "spread": float(frames.std())}))
"""


def _env(**overrides) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    return env | overrides


def mp4_frames(path) -> tuple[dict, int]:
    """The video's header (codec, size, frame rate) and its frame count, as ffmpeg reads them."""
    reader = imageio_ffmpeg.read_frames(str(path))
    header = next(reader)
    return header, sum(1 for _ in reader)


def test_render_writes_a_filmstrip_png_an_mp4_and_a_gif(tmp_path):
    backend = headless_gl_backend()
    if backend is None:
        pytest.skip("no headless OpenGL here (neither libOSMesa nor a GPU with libEGL)")
    done = subprocess.run([sys.executable, "-c", RENDER_SCRIPT, str(tmp_path)], capture_output=True, text=True,
                          env=_env(MUJOCO_GL=backend), timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if "error" in result:
        pytest.skip(f"this machine cannot render with MUJOCO_GL={backend}: {result['error']}")
    from PIL import Image

    assert result["shape"] == [3, 48, 64, 3] and result["spread"] > 5  # not a blank image
    assert Image.open(tmp_path / "strip.png").size == (128, 96)         # 2 columns, 2 rows
    assert Image.open(tmp_path / "gait.gif").n_frames == 3
    header, frames = mp4_frames(tmp_path / "gait.mp4")
    assert (header["codec"], header["size"], header["fps"], frames) == ("h264", (64, 48), 25.0, 3)


def test_mp4_frames_are_whole_macroblocks(tmp_path):
    with pytest.raises(ValueError, match="multiples of 16"):
        write_mp4(np.zeros((2, 50, 64, 3), np.uint8), tmp_path / "odd.mp4", 0.04)


def test_missing_opengl_is_one_line_and_nonzero(tmp_path):
    # GLFW with no display stands for a machine without headless OpenGL.
    done = subprocess.run([sys.executable, "-m", "mjxcpg", "render", "--run", str(tmp_path / "none")],
                          capture_output=True, text=True, env=_env(MUJOCO_GL="glfw"), timeout=300)
    assert done.returncode != 0
    err = done.stderr.strip()
    assert err.startswith("mjxcpg: error: cannot render") and "OpenGL" in err and "\n" not in err


def test_earlier_render_is_replaced_only_with_force(tmp_path):
    """Refused before OpenGL is checked or anything walks (GLFW with no display would fail
    next): the earlier filmstrip stays as it was."""
    earlier = tmp_path / "run" / "render" / "gait_learner00_nominal.png"
    earlier.parent.mkdir(parents=True)
    earlier.write_bytes(b"an earlier filmstrip")
    done = subprocess.run([sys.executable, "-m", "mjxcpg", "render", "--run", str(tmp_path / "run")],
                          capture_output=True, text=True, env=_env(MUJOCO_GL="glfw"), timeout=300)
    assert done.returncode != 0
    err = done.stderr.strip()
    assert err.startswith("mjxcpg: error:") and "earlier render" in err and "--force" in err and "\n" not in err
    assert earlier.read_bytes() == b"an earlier filmstrip"


def test_only_render_chooses_the_gl_back_end():
    script = ("import os, sys; from mjxcpg import cli; cli._choose_headless_gl(sys.argv[1:]); "
              "print(os.environ.get('MUJOCO_GL'), 'mujoco' in sys.modules)")
    for command, expected in (("walk", None), ("render", headless_gl_backend())):
        done = subprocess.run([sys.executable, "-c", script, command], capture_output=True, text=True,
                              env=_env(), timeout=120, check=True)
        assert done.stdout.split() == [str(expected), "False"]


@pytest.mark.slow
def test_render_command_on_a_learned_run(tmp_path):
    backend = headless_gl_backend()
    if backend is None:
        pytest.skip("no headless OpenGL here (neither libOSMesa nor a GPU with libEGL)")
    run = make_learned_run(tmp_path / "run")
    done = subprocess.run([sys.executable, "-m", "mjxcpg", "render", "--run", str(run), "--seconds", "4.5",
                           "--out", str(tmp_path / "pictures"), "--json"], capture_output=True, text=True,
                          env=_env(), timeout=900)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["gl"] == backend and result["frames_png"] == 20 and not result["fell"]
    assert (tmp_path / "pictures" / "gait_learner00_nominal.png").is_file()
    assert not (tmp_path / "pictures" / "gait_learner00_nominal.gif").exists()  # only with --gif
    header, frames = mp4_frames(tmp_path / "pictures" / "gait_learner00_nominal.mp4")
    # a frame every 0.04 s from 0 to 4.44 s of the 4.5 s walk; the default view is 240 x 320
    assert (header["size"], frames, result["frames_video"]) == ((240, 320), 112, 112)
