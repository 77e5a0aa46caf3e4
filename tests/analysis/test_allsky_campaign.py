"""The all-sky campaign (issue 26 part 3, docs/all-sky.md): simulated 180–190° fisheye frames,
equidistant and Kannala–Brandt, 2–4 MP, with a horizon, trees and a light dome, solved with no
hint and no camera file: at least 95 % solved, none wrong, the boresight's median error ≤ 30″."""

import pytest

from skyfix.analysis.allsky_campaign import allsky_campaign, allsky_frame, summarise


def test_allsky_frames_draw_every_kind():
    _, camera, lens = allsky_frame(7)
    assert camera.projection == "kannala-brandt" and 1.9e6 < camera.width * camera.height < 4.3e6
    assert lens


@pytest.mark.slow
def test_allsky_campaign_40_frames():
    results = allsky_campaign(range(40))
    s = summarise(results)
    assert s["wrong"] == 0
    assert s["solved"] >= 38, [r.reason for r in results if not r.solved]
    assert s["boresight_median_arcsec"] <= 30.0
    assert {r.lens for r in results} == {"equidistant 180°", "equidistant 190°", "KB equisolid 180°",
                                         "KB random 185°"}
