"""The phantom's lighting programs: hivar's varying, off-centre light and the true shading."""

import json

import numpy as np
import pytest

from surgsplat.data.phantom import PhantomConfig, generate_phantom
from surgsplat.data.scene import read_image


@pytest.mark.slow
def test_hivar_light_varies_and_the_shading_explains_the_images(tmp_path, small_phantom,
                                                                 cli, one_error_line):
    root = generate_phantom(PhantomConfig(preset="small", lighting="hivar"), tmp_path / "hivar")
    exposure = np.array(json.loads((root / "gt" / "exposure.json").read_text()))
    intensity = np.array(json.loads((root / "gt" / "light_intensity.json").read_text()))
    assert exposure.max() / exposure.min() >= 2.0 and intensity.max() / intensity.min() >= 2.0
    shadings = []
    for index in (0, 7, 15):
        albedo = read_image(root / "gt" / "albedo" / f"{index:06d}.png") / 255.0
        tissue = read_image(root / "gt" / "tissue_images" / f"{index:06d}.png") / 255.0
        shading = np.load(root / "gt" / "shading" / f"{index:06d}.npy")
        diffuse = np.clip(albedo * shading[..., None], 0.0, 1.0)
        # image = albedo * shading + a non-negative specular, clipped and quantised
        assert (tissue >= diffuse - 2.5 / 255).all()
        assert np.median(np.abs(tissue - diffuse)) < 2.0 / 255
        shadings.append(shading / shading.mean())
    # the light circles off the camera centre: the shading's pattern moves, not just its level
    assert np.abs(shadings[0] - shadings[2]).mean() > 0.02
    # the standard phantom is unchanged: no shading files, no lighting entry
    assert not (small_phantom / "gt" / "shading").exists()
    assert "lighting" not in json.loads((small_phantom / "scene.json").read_text())["extra"]
    assert "valid lightings: standard, livar, hivar" in one_error_line(
        cli("phantom", "--out", str(tmp_path / "x"), "--lighting", "bright"))
