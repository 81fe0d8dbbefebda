"""Reading frames from videos and folders, in natural order, with a frame selection."""

from pathlib import Path

import cv2
import imageio
import numpy as np
import pytest

from surgsplat.data.frames_source import FrameSource, list_frame_files, name_numbers
from surgsplat.errors import DataError

from .conftest import FRAMES, HEIGHT, WIDTH, endoscope_frames


def test_folder_sorted_naturally_and_filtered_by_pattern(tmp_path: Path):
    for n in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"frame_{n}_endo.png"), np.full((4, 6, 3), n, np.uint8))
        cv2.imwrite(str(tmp_path / f"frame_{n}_endo_mask.png"), np.zeros((4, 6), np.uint8))
    names = [p.name for p in list_frame_files(tmp_path, "*_endo.png")]
    assert names == ["frame_1_endo.png", "frame_2_endo.png", "frame_10_endo.png"]
    source = FrameSource(tmp_path, "*_endo.png")
    assert [int(f[0, 0, 0]) for _, f in source.read([0, 2])] == [1, 10]
    assert name_numbers(Path("frame_561_endo_watershed_mask.png")) == (561,)


def test_video_frames_read_by_index(video: Path):
    source = FrameSource(video)
    assert source.is_video and source.count == FRAMES
    truth = endoscope_frames()
    read = dict(source.read([1, 4, 9]))
    assert sorted(read) == [1, 4, 9]
    for index, frame in read.items():
        assert frame.shape == (HEIGHT, WIDTH, 3) and frame.dtype == np.uint8
        # MJPG is lossy: frames agree with the originals on average within 25 grey levels.
        assert np.abs(frame.astype(int) - truth[index]).mean() < 25


def test_mp4_written_by_imageio_reads(tmp_path: Path):
    path = tmp_path / "clip.mp4"
    with imageio.get_writer(path, fps=10, macro_block_size=16) as writer:
        for i in range(5):
            writer.append_data(np.full((HEIGHT, WIDTH, 3), 40 * i, np.uint8))
    source = FrameSource(path)
    assert source.count == 5
    (_, last), = source.read([4])
    assert abs(float(last.mean()) - 160) < 4  # lossy H.264: within 4 grey levels


def test_bad_sources_name_the_file(tmp_path: Path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.mp4").write_text("not a video")
    cv2.imwrite(str(tmp_path / "one.png"), np.zeros((4, 4), np.uint8))
    for name, problem in [("missing.mp4", "does not exist"), ("empty", "holds no frame image"),
                          ("bad.mp4", "cannot be opened as a video"), ("one.png", "single image")]:
        with pytest.raises(DataError, match=problem) as err:
            FrameSource(tmp_path / name)
        assert err.value.path == tmp_path / name


def test_a_cut_video_is_named_in_every_message(video, tmp_path, capfd):
    """A video cut short: the import stops or warns, and whatever the decoder prints reaches
    the user only with the video's name."""
    import warnings

    cut = tmp_path / "cut.avi"
    data = video.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        try:
            source = FrameSource(cut)
            frames = list(source.read(list(range(source.count))))
        except DataError as err:
            assert str(cut) in str(err)
        else:
            assert 0 < len(frames) < len(endoscope_frames())
    assert all(str(cut) in str(w.message) for w in seen)
    assert capfd.readouterr().err == ""  # nothing the decoder printed went out unnamed
