"""Headless pictures of a learned gait: a filmstrip PNG (snapshots every 0.1 s, like the
paper's Fig 6), an MP4 video (H.264, through the ffmpeg that imageio-ffmpeg ships) and, on
request, an animated GIF.

The walk is the learned policy's mean (no exploration noise) from the standing pose, run by
the usual jitted ``walk.make_walk`` with each period's configuration recorded; MuJoCo's
``Renderer`` then draws the recorded configurations off-screen.  OpenGL comes from EGL when
a GPU is present and from OSMesa (Debian ``libosmesa6``) otherwise: ``headless_gl_backend``
picks one, and the ``render`` command sets ``MUJOCO_GL`` to it before MuJoCo is imported
(MuJoCo reads it once, at import).  Without OpenGL the renderer raises ``RenderError``
with one line saying so.
"""

from __future__ import annotations

import copy
import ctypes.util
import dataclasses
import glob
import os
import warnings
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from mjxcpg import robots
from mjxcpg.robots.description import RobotDescription
from mjxcpg.robots.qrio import QRIO


class RenderError(RuntimeError):
    """No usable OpenGL: one line for the user."""


def headless_gl_backend() -> str | None:
    """``egl`` when a GPU device node and libEGL exist, else ``osmesa`` when libOSMesa
    does, else None (no headless OpenGL found).  Imports nothing from MuJoCo."""
    gpu = os.path.exists("/dev/nvidia0") or bool(glob.glob("/dev/dri/renderD*"))
    if gpu and ctypes.util.find_library("EGL"):
        return "egl"
    if ctypes.util.find_library("OSMesa"):
        return "osmesa"
    return None


@dataclasses.dataclass(frozen=True)
class View:
    """Image size, a camera that tracks the robot's centre of mass from its left side, and
    a brighter headlight than the model's (the model's light is for a viewer)."""

    width: int = 240
    height: int = 320
    distance: float = 1.0     # m, for QRIO's 0.24 m leg; scaled with the robot's (``for_robot``)
    azimuth: float = 90.0     # degrees; 90 looks along -y at the robot's left side
    elevation: float = -10.0  # degrees
    headlight: float = 0.6    # ambient and diffuse intensity of the camera's headlight
    tracked_body: str = QRIO.pelvis

    def for_robot(self, robot: RobotDescription) -> "View":
        """This view of ``robot``: the camera as far from it, in leg lengths, as from QRIO."""
        return dataclasses.replace(self, distance=self.distance * robot.leg_length / QRIO.leg_length,
                                   tracked_body=robot.pelvis)


@dataclasses.dataclass
class Gait:
    """A recorded walk: configurations at every control period of one robot."""

    model: object             # the mujoco.MjModel that was simulated
    qpos: np.ndarray          # (steps, nq)
    dt: float                 # control period (s)
    fell: bool
    seconds: float            # simulated time before a fall (or the whole walk)
    mean_vx: float
    robot: RobotDescription   # the platform that walked


def record_gait(run_dir: Path, learner: int, seconds: float, engine: str | None = None,
                robot: str = "nominal") -> Gait:
    """Walk learner ``learner``'s final policy of the run in ``run_dir`` for ``seconds``."""
    import jax

    from mjxcpg.control import walk
    from mjxcpg.learning.learner import actor_feedback
    from mjxcpg.training import runs

    spec, sim, task, state = runs.load_run(run_dir, engine, robot=robot)
    runs.check_learners(spec, [learner])
    weights = jax.tree.map(lambda w: w[learner:learner + 1], state.learners.weights)
    trace = walk.walk_from_standing(sim, actor_feedback(task), weights, seconds, record_qpos=True)
    summary = walk.summarise(trace, sim.control_dt, sim.layout.weight)[0]
    return Gait(model=sim.model, qpos=np.asarray(trace.qpos[0], np.float64), dt=sim.control_dt,
                fell=summary.fell, seconds=summary.seconds, mean_vx=summary.mean_vx,
                robot=robots.platform(spec.platform))


def open_renderer(model, width: int, height: int):
    """A ``mujoco.Renderer``, or ``RenderError`` in one line when OpenGL is not usable."""
    import mujoco

    try:
        with warnings.catch_warnings():  # GLFW warns before it fails; the error below says it all
            warnings.simplefilter("ignore")
            return mujoco.Renderer(model, height, width)
    except Exception as error:  # GL back ends fail with many exception types
        backend = os.environ.get("MUJOCO_GL", "unset")
        detail = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise RenderError(f"cannot render: no usable OpenGL (MUJOCO_GL={backend}: {detail}); "
                          "install libosmesa6 (Debian) or use a machine with a GPU and EGL") from None


def check_opengl() -> None:
    """Draw one tiny image, or raise ``RenderError``."""
    import mujoco

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
    renderer = open_renderer(model, 16, 16)
    try:
        renderer.update_scene(mujoco.MjData(model))
        renderer.render()
    finally:
        renderer.close()


def render_frames(model, qpos: np.ndarray, view: View = View()) -> np.ndarray:
    """(frames, height, width, 3) uint8 images of the configurations ``qpos`` (frames, nq)."""
    import mujoco

    model = copy.deepcopy(model)
    model.vis.headlight.ambient[:] = view.headlight / 2
    model.vis.headlight.diffuse[:] = view.headlight
    renderer = open_renderer(model, view.width, view.height)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    camera.trackbodyid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, view.tracked_body)
    camera.distance, camera.azimuth, camera.elevation = view.distance, view.azimuth, view.elevation
    data = mujoco.MjData(model)
    frames = np.empty((len(qpos), view.height, view.width, 3), np.uint8)
    try:
        for k, q in enumerate(qpos):  # host-side drawing, one image per recorded configuration
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)  # the subtree centre of mass the camera tracks
            renderer.update_scene(data, camera)
            frames[k] = renderer.render()
    finally:
        renderer.close()
    return frames


def snapshot_steps(start: float, stop: float, interval: float, dt: float, steps: int) -> np.ndarray:
    """Indices of the control periods nearest to the times start, start + interval, ... < stop
    (within half a period of each), inside a walk of ``steps`` periods."""
    times = start + interval * np.arange(max(1, int(np.floor((stop - start) / interval + 1e-9))))
    return np.unique(np.clip(np.round(times / dt).astype(int), 0, steps - 1))


def filmstrip(frames: np.ndarray, times: np.ndarray, columns: int = 10):
    """The frames side by side, ``columns`` a row, each labelled with its time: a PIL image."""
    from PIL import Image, ImageDraw

    n, h, w, _ = frames.shape
    rows = -(-n // columns)
    sheet = Image.new("RGB", (min(n, columns) * w, rows * h), "white")
    draw = ImageDraw.Draw(sheet)
    for k, (frame, t) in enumerate(zip(frames, times)):
        x, y = (k % columns) * w, (k // columns) * h
        sheet.paste(Image.fromarray(frame), (x, y))
        draw.text((x + 4, y + 4), f"{t:.1f} s", fill="white")
    return sheet


def write_gif(frames: np.ndarray, path: Path, frame_seconds: float) -> None:
    """An endlessly looping GIF, one frame every ``frame_seconds``."""
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], loop=0,
                   duration=round(frame_seconds * 1000), optimize=False)


def write_mp4(frames: np.ndarray, path: Path, frame_seconds: float) -> None:
    """An H.264 MP4 (yuv420p, which every player reads), one frame every ``frame_seconds``.
    Width and height must be multiples of 16, H.264's macroblock."""
    _, height, width, _ = frames.shape
    if width % 16 or height % 16:
        raise ValueError(f"MP4 frames must be multiples of 16 pixels wide and high, got {width}x{height}")
    writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=1.0 / frame_seconds, codec="libx264",
                                         pix_fmt_out="yuv420p", ffmpeg_log_level="error")
    writer.send(None)  # starts ffmpeg
    for frame in frames:
        writer.send(np.ascontiguousarray(frame))
    writer.close()


def render_gait(run_dir: Path, learner: int, out: Path, seconds: float = 10.0, strip_start: float = 2.0,
                strip_seconds: float = 2.0, snapshot_s: float = 0.1, video_frame_s: float = 0.04,
                engine: str | None = None, robot: str = "nominal", view: View = View(), gif: bool = False,
                force: bool = False) -> dict:
    """Walk the policy for ``seconds``; write ``out``/gait_learnerK_ROBOT.png (snapshots every
    ``snapshot_s`` from ``strip_start`` for ``strip_seconds``) and .mp4 (the whole walk, a
    frame every ``video_frame_s``), and with ``gif`` the same frames as a .gif; earlier files
    of those names are replaced only with ``force``.

    Checks that OpenGL works and that ``out`` may be written before the walk is simulated."""
    if strip_start + strip_seconds > seconds:
        raise ValueError(f"the filmstrip ({strip_start:g} s + {strip_seconds:g} s) must lie within "
                         f"the walk's {seconds:g} s")
    from mjxcpg.training import runs

    stem = out / f"gait_learner{learner:02d}_{robot}"
    runs.refuse_earlier_output(out, tuple(stem.with_suffix(s).name for s in (".png", ".mp4", ".gif")), force,
                               "render")
    check_opengl()
    gait = record_gait(run_dir, learner, seconds, engine, robot)
    steps = len(gait.qpos)
    strip_steps = snapshot_steps(strip_start, strip_start + strip_seconds, snapshot_s, gait.dt, steps)
    video_steps = snapshot_steps(0.0, seconds, video_frame_s, gait.dt, steps)
    out.mkdir(parents=True, exist_ok=True)
    view = view.for_robot(gait.robot)
    filmstrip(render_frames(gait.model, gait.qpos[strip_steps], view),
              strip_steps * gait.dt).save(stem.with_suffix(".png"))
    video = render_frames(gait.model, gait.qpos[video_steps], view)
    write_mp4(video, stem.with_suffix(".mp4"), video_frame_s)
    written = {"png": str(stem.with_suffix(".png")), "mp4": str(stem.with_suffix(".mp4"))}
    if gif:
        write_gif(video, stem.with_suffix(".gif"), video_frame_s)
        written["gif"] = str(stem.with_suffix(".gif"))
    return written | {"frames_png": len(strip_steps), "frames_video": len(video_steps), "fell": gait.fell,
                      "walked_seconds": gait.seconds, "mean_vx": gait.mean_vx, "robot": robot,
                      "gl": os.environ.get("MUJOCO_GL", "default")}
