"""The camera of an import: --fx/--fy/--cx/--cy, OpenCV calibration files, bad input."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError, SurgsplatError

from .conftest import HEIGHT, WIDTH

# A real calibrated endoscope pair has non-square pixels and an off-centre principal point.
FX, FY, CX_CV, CY_CV = 43.9, 46.9, 50.5, 28.0  # OpenCV convention: pixel centres at integers


@pytest.fixture
def frames(tmp_path: Path) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"),
                    rng.integers(60, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8))
    return folder


def write_calibration(path: Path, **entries) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        storage.write(key, value)
    storage.release()
    return path


def camera_matrix() -> np.ndarray:
    return np.array([[FX, 0.0, CX_CV], [0.0, FY, CY_CV], [0.0, 0.0, 1.0]])


def camera_of(scene_dir: Path) -> tuple[float, float, float, float]:
    camera = load_scene(scene_dir).camera
    return camera.fx, camera.fy, camera.cx, camera.cy


def test_fx_fy_cx_cy_scaled_with_the_frames(frames: Path, tmp_path: Path):
    config = ImportConfig(fx=FX, fy=FY, cx=CX_CV, cy=CY_CV, scale=0.5, fov_mask=False)
    out = import_scene(frames, tmp_path / "s", config)
    # OpenCV's principal point + 0.5 px, then everything halves with the image (float32 K).
    expected = (FX / 2, FY / 2, (CX_CV + 0.5) / 2, (CY_CV + 0.5) / 2)
    np.testing.assert_allclose(camera_of(out), expected, rtol=1e-6)
    stored = json.loads((out / "scene.json").read_text())["intrinsics"]
    np.testing.assert_allclose([stored[k] for k in ("fx", "fy", "cx", "cy")], expected,
                               rtol=1e-12)


def test_default_principal_point_is_the_image_centre(frames: Path, tmp_path: Path):
    out = import_scene(frames, tmp_path / "s", ImportConfig(focal=40.0, fov_mask=False))
    assert camera_of(out) == (40.0, 40.0, WIDTH / 2, HEIGHT / 2)


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_calibration_file_camera_matrix(frames: Path, tmp_path: Path, suffix: str):
    calibration = write_calibration(tmp_path / f"calib{suffix}", image_width=WIDTH,
                                    image_height=HEIGHT, camera_matrix=camera_matrix(),
                                    distortion_coefficients=np.zeros((1, 5)))
    out = import_scene(frames, tmp_path / "s", ImportConfig(calibration=calibration,
                                                            fov_mask=False))
    np.testing.assert_allclose(camera_of(out), (FX, FY, CX_CV + 0.5, CY_CV + 0.5), rtol=1e-6)
    extra = json.loads((out / "scene.json").read_text())["extra"]
    assert "camera_matrix" in extra["camera_source"]


def test_calibration_file_rectified_stereo_camera(frames: Path, tmp_path: Path):
    """OpenCV stereo_calib's M1/D1 (distorted) plus stereoRectify's P1: the rectified camera."""
    rectified = np.array([[45.0, 0.0, 47.25, 0.0], [0.0, 45.0, 31.75, 0.0], [0.0, 0.0, 1.0, 0.0]])
    calibration = write_calibration(tmp_path / "stereo.yml", M1=camera_matrix(),
                                    D1=np.array([[0.1, -0.02, 0, 0, 0]]), P1=rectified)
    out = import_scene(frames, tmp_path / "s", ImportConfig(calibration=calibration,
                                                            fov_mask=False))
    np.testing.assert_allclose(camera_of(out), (45.0, 45.0, 47.75, 32.25), rtol=1e-6)


@pytest.mark.parametrize("entries,fragment", [
    ({"image_width": WIDTH}, "holds no camera matrix"),
    ({"K": np.eye(2)}, "K must be a 3x3 matrix"),
    ({"M1": np.array([[0.0, 0, 40], [0, 40, 30], [0, 0, 1]])}, "must be positive"),
    ({"M1": np.array([[40.0, 0, 40], [0, 40, 30], [0, 0, 1]]),
      "D1": np.array([[0.1, 0, 0]])}, "D1 must hold 4, 5, 8, 12 or 14"),
    ({"camera_matrix": np.array([[40.0, 0, 40], [0, 40, 30], [0, 0, 1]]),
      "image_width": 2 * WIDTH, "image_height": 2 * HEIGHT}, "is for 192x128 (WxH) images"),
])
def test_bad_calibration_files_are_named(frames: Path, tmp_path: Path, entries: dict,
                                         fragment: str):
    calibration = write_calibration(tmp_path / "bad.yml", **entries)
    with pytest.raises(DataError, match=fragment.replace("(", r"\(").replace(")", r"\)")) as info:
        import_scene(frames, tmp_path / "s", ImportConfig(calibration=calibration))
    assert info.value.path == calibration
    assert not (tmp_path / "s").exists()


def smooth_pattern(height: int, width: int) -> np.ndarray:
    """uint8 [H, W, 3]: smooth waves (periods of 9-15 px), so that resampling is accurate."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    waves = [np.sin(xs / 2.1 + ys / 3.3), np.sin(ys / 1.6 - xs / 4.0), np.cos((xs + ys) / 2.4)]
    return np.stack([np.rint(127.5 + 100 * w) for w in waves], axis=-1).astype(np.uint8)


def test_distorted_frames_are_undistorted_to_the_camera_matrix(tmp_path: Path):
    """Frames seen through barrel distortion come out as the ideal pinhole image of the same
    camera matrix, and the tool mask moves with them."""
    matrix, distortion = camera_matrix(), np.array([-0.25, 0.08, 0.001, -0.002, 0.0])
    ideal = smooth_pattern(HEIGHT, WIDTH)
    ideal_tool = np.zeros((HEIGHT, WIDTH), bool)
    ideal_tool[8:20, 60:85] = True  # a box near the edge, where distortion moves it most
    # Distort: pixel p of the source shows the ideal image at p undistorted (OpenCV pixels).
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    where = cv2.undistortPoints(np.stack([xs, ys], -1).reshape(-1, 1, 2), matrix, distortion,
                                P=matrix).reshape(HEIGHT, WIDTH, 2).astype(np.float32)
    source = cv2.remap(ideal, where[..., 0], where[..., 1], cv2.INTER_LINEAR)
    source_tool = cv2.remap(ideal_tool.astype(np.uint8), where[..., 0], where[..., 1],
                            cv2.INTER_NEAREST).astype(bool)
    frames, masks = tmp_path / "frames", tmp_path / "masks"
    frames.mkdir()
    masks.mkdir()
    cv2.imwrite(str(frames / "0.png"), source[..., ::-1])
    cv2.imwrite(str(masks / "0.png"), source_tool.astype(np.uint8) * 255)
    calibration = write_calibration(tmp_path / "calib.yml", camera_matrix=matrix,
                                    distortion_coefficients=distortion[None])
    out = import_scene(frames, tmp_path / "s", ImportConfig(calibration=calibration, masks=masks,
                                                            fov_mask=False))
    frame = load_scene(out).frames[0]
    np.testing.assert_allclose(camera_of(out), (FX, FY, CX_CV + 0.5, CY_CV + 0.5), rtol=1e-6)
    inner = (slice(6, HEIGHT - 6), slice(6, WIDTH - 6))  # away from the corners left empty
    undistorted = frame.image.numpy()[inner] * 255
    error = np.abs(undistorted - ideal[inner]).mean()
    before = np.abs(source[inner].astype(float) - ideal[inner]).mean()
    assert error < 6.0 and before > 8 * error, (error, before)  # grey levels of 255 (4.3, 57)
    tool = frame.tool.numpy()
    assert (tool & ideal_tool).sum() / (tool | ideal_tool).sum() > 0.9  # IoU
    stereo = ImportConfig(calibration=calibration, right=frames, disparity_only=True)
    with pytest.raises(DataError, match="stereo needs rectified frames"):
        import_scene(frames, tmp_path / "t", stereo)


def test_unparsable_or_missing_calibration_file(frames: Path, tmp_path: Path):
    (tmp_path / "broken.yml").write_text("%YAML:1.0\ncamera_matrix: [1, 2\n")
    with pytest.raises(DataError, match="cannot be parsed"):
        import_scene(frames, tmp_path / "s", ImportConfig(calibration=tmp_path / "broken.yml"))
    with pytest.raises(DataError, match="does not exist"):
        import_scene(frames, tmp_path / "s", ImportConfig(calibration=tmp_path / "none.yml"))


@pytest.mark.parametrize("config,fragment", [
    (ImportConfig(fx=-3.0, fy=40.0), "--fx must be positive"),
    (ImportConfig(fx=40.0), "--fx and --fy go together"),
    (ImportConfig(cx=20.0), "--cx and --cy go together"),
    (ImportConfig(focal=40.0, fx=40.0, fy=40.0), "either --focal or --fx"),
    (ImportConfig(focal=40.0, calibration=Path("c.yml")), "either --calibration"),
    (ImportConfig(focal=40.0, cx=500.0, cy=10.0), "outside the 96x64"),
])
def test_inconsistent_camera_options(frames: Path, tmp_path: Path, config: ImportConfig,
                                     fragment: str):
    with pytest.raises(SurgsplatError, match=fragment):
        import_scene(frames, tmp_path / "s", config)


def test_cli_fx_fy_cx_cy(frames: Path, tmp_path: Path, cli):
    result = cli("import", str(frames), "--out", str(tmp_path / "s"), "--fx", str(FX),
                 "--fy", str(FY), "--cx", str(CX_CV), "--cy", str(CY_CV), "--no-fov-mask")
    assert result.returncode == 0, result.stderr
    assert "fy 46.90" in result.stdout and "given: --fx, --fy" in result.stdout
    np.testing.assert_allclose(camera_of(tmp_path / "s"), (FX, FY, CX_CV + 0.5, CY_CV + 0.5),
                               rtol=1e-6)
