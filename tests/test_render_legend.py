"""The legend drawn into rendered episodes: it names every colour the frames use, and sits beside every frame."""

import numpy as np
import pytest
from PIL import Image

from sb3_latentswarm.envs.swarm_recon import AGENT_COLOURS, RENDER_COLOURS
from sb3_latentswarm.presets import get_preset
from sb3_latentswarm.rendering import LEGEND_WIDTH, legend_figure, render_episode


def legend_texts(fig) -> list[str]:
    (legend,) = fig.legends
    return [text.get_text() for text in legend.get_texts()]


def test_legend_names_every_element_the_frames_draw():
    fig = legend_figure(3, "proposed, episode seed 7\nsampled actions")
    texts = legend_texts(fig)
    for element in ("coverage bar", "not yet seen", "seen, free", "seen, obstacle", "obstacle not yet seen",
                    "sensor footprint", "link, both ways", "link, one way", "red border", "dropout"):
        assert any(element in text for text in texts), (element, texts)
    assert [text for text in texts if text.startswith("uav_")] == [f"uav_{i}: square, trail" for i in range(3)]
    assert fig.texts[0].get_text() == "proposed, episode seed 7\nsampled actions"
    # one legend colour per map colour the frames use (the patches' face colours, 0-1)
    faces = {tuple(np.round(np.array(patch.get_facecolor()[:3]) * 255).astype(int)) for patch in fig.legends[0].get_patches()}
    for name in ("unseen", "free", "obstacle", "obstacle_unseen", "coverage"):
        assert RENDER_COLOURS[name] in faces, name


def test_legend_groups_uavs_that_share_a_colour():
    texts = legend_texts(legend_figure(len(AGENT_COLOURS) + 2))
    assert "uav_0, uav_7: square, trail" in texts and "uav_6: square, trail" in texts
    with pytest.raises(ValueError, match="n_agents must be >= 1"):
        legend_figure(0)


def test_rendered_frames_carry_the_legend_panel(tmp_path):
    config = get_preset("smoke").config
    with_legend = render_episode(None, config, tmp_path / "legend.gif", fps=10, max_frames=4)
    without = render_episode(None, config, tmp_path / "plain.gif", fps=10, max_frames=4, legend=False)
    wide, plain = Image.open(with_legend), Image.open(without)
    assert wide.size[0] == plain.size[0] + LEGEND_WIDTH and wide.size[1] >= plain.size[1]
    assert wide.info["duration"] == 100 and wide.n_frames == plain.n_frames
