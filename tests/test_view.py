"""phri view: the replay of an episode log, its page in headless Chromium, the loopback server and
bad input."""

from __future__ import annotations

import shutil
import subprocess
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import run_without

from phri import load_task
from phri._extras import EXTRA_OF
from phri._phri import Robot
from phri.cli import main
from phri.exceptions import InvalidParameterError, LogError
from phri.view import ReplayServer, read_log, replay_data, write_replay

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from phri.sim.episode import EpisodeConfig, run_episode
    from phri.sim.participant import ParticipantParams
    from phri.sim.world import World

    task = load_task("laptop")
    path = tmp_path_factory.mktemp("view") / "laptop_learning.npz"
    with World(scene=task.scene) as world:
        run_episode(
            task, world, ParticipantParams(), EpisodeConfig(strategy="learning"), seed=3, log_path=path
        )
    return path


def test_replay_places_the_spheres_where_the_robot_model_does(log_path: Path) -> None:
    log = read_log(log_path)
    data = replay_data(log)
    robot = Robot.jaco2()
    t = np.asarray(log["t"])
    k = len(data["frames"]["t"]) // 2
    row = int(np.argmin(np.abs(t - data["frames"]["t"][k])))
    centers, radii, frame = robot.collision_spheres(robot.collision_bodies[3])
    pose = robot.frame_pose(frame, log["q"][row])
    want = centers @ pose[:3, :3].T + pose[:3, 3]
    start = int(np.searchsorted(log["sphere_bodies"], 3))
    got = np.array(data["frames"]["spheres"][k][start : start + len(radii)])
    np.testing.assert_allclose(got, want, atol=1e-3)
    assert [o["name"] for o in data["objects"]] == load_task("laptop").scene.names


def test_bad_logs_are_typed_errors_naming_the_file(tmp_path: Path, log_path: Path) -> None:
    junk = tmp_path / "junk.npz"
    junk.write_text("not a log")
    with pytest.raises(LogError, match="junk.npz"):
        read_log(junk)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.zeros(3))
    with pytest.raises(LogError, match="not a phri episode log"):
        read_log(foreign)
    log = dict(np.load(log_path))
    del log["sphere_radii"]
    old = tmp_path / "old.npz"
    np.savez(old, **log)
    with pytest.raises(LogError, match="does not record its robot and scene"):
        read_log(old)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(log_path.read_bytes()[:1000])
    with pytest.raises(LogError):
        read_log(truncated)
    assert main(["view", str(junk), "--html", str(tmp_path / "x.html")]) == 2


def test_the_page_is_self_contained(tmp_path: Path, log_path: Path) -> None:
    out = write_replay(log_path, tmp_path / "replay.html")
    text = out.read_text(encoding="utf-8")
    assert 'src="http' not in text and 'href="http' not in text
    assert "<script src=" not in text  # every script inline
    with pytest.raises(FileExistsError):
        write_replay(log_path, out)


def test_the_viewer_needs_no_extra(tmp_path: Path, log_path: Path) -> None:
    """Without any extra (numpy only), ``phri view`` writes the page: three.js is bundled."""
    done = run_without({*EXTRA_OF, "scipy"}, f"""
        import sys
        from phri.cli import main
        print("exit", main(["view", {str(log_path)!r}, "--html", "replay.html"]))
        print("loaded", sorted(m for m in sys.modules if m.partition(".")[0] in set(sys.argv[1].split(","))))
    """, tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "exit 0" in done.stdout and "loaded []" in done.stdout, done.stdout
    assert (tmp_path / "replay.html").stat().st_size > 100_000


def test_the_server_listens_on_loopback_only(log_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="loopback"):
        ReplayServer(lambda p: "", host="0.0.0.0")
    page = "<!doctype html><p>hello</p>"
    with ReplayServer(lambda p: page if p == "/" else None, host="127.0.0.1", port=0) as server:
        assert server.address[0] == "127.0.0.1"
        with urllib.request.urlopen(server.url, timeout=10) as r:
            assert r.read().decode() == page


def _screenshot(page: Path, t: float, out: Path) -> np.ndarray:
    import matplotlib.image

    subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
         "--window-size=1200,700", "--virtual-time-budget=3000", f"--screenshot={out}",
         f"{page.as_uri()}?t={t}"],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    return matplotlib.image.imread(out)[..., :3]


def test_chromium_shows_the_arm_and_the_scene_and_the_arm_moves(tmp_path: Path, log_path: Path) -> None:
    if CHROMIUM is None:
        pytest.fail("chromium is missing: apt-get install chromium (.ci/run installs it)")
    page = write_replay(log_path, tmp_path / "replay.html")
    early, late = _screenshot(page, 0.0, tmp_path / "a.png"), _screenshot(page, 12.0, tmp_path / "b.png")
    view = slice(40, 650), slice(0, 700)  # the 3D view, left of the plots

    def mask(img: np.ndarray, rgb: tuple[int, int, int], tol: float = 0.12) -> np.ndarray:
        return np.abs(img[view] - np.array(rgb) / 255).max(axis=2) < tol

    arm_a, arm_b = mask(early, (255, 127, 14), 0.2), mask(late, (255, 127, 14), 0.2)
    table = mask(early, (200, 162, 122), 0.15)
    assert arm_a.mean() > 0.005 and arm_b.mean() > 0.005, "no arm on the page"
    assert table.mean() > 0.02, "no table on the page"
    assert (arm_a ^ arm_b).mean() > 0.2 * arm_a.mean(), "the arm did not move between 0 s and 12 s"
