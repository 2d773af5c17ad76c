"""Presets and settings changed by name (pipeline/params.py)."""

import pytest

from pipeline.params import get_preset


def test_settings_are_read_as_their_fields_types():
    p = get_preset("default").with_settings(["sweep.min_agree=2", "geometry.recon_rescue_planar=off",
                                             "max_side=800", "sweep.lab_weights=1,1,1", "aggregate.threshold=0.4"])
    assert p.sweep.min_agree == 2 and p.geometry.recon_rescue_planar is False and p.max_side == 800
    assert p.sweep.lab_weights == (1.0, 1.0, 1.0) and p.aggregate.threshold == 0.4
    assert p.preset == "default" and p.sweep.smooth_p2 == get_preset("default").sweep.smooth_p2    # the rest kept
    assert get_preset("default").sweep.min_agree == 1                                              # presets untouched


@pytest.mark.parametrize("setting,expect", [
    ("sweep.min_agree=two", "'two' is not a whole number"),
    ("sweep.nope=1", "no field 'nope' in sweep"),
    ("swep.min_agree=1", "no section 'swep'"),
    ("min_agree", "expected SECTION.FIELD=VALUE"),
    ("geometry.reconstruction=maybe", "'maybe' is not true or false"),
    ("sweep=1", "no field 'sweep' at the top level"),
    ("preset=paper", "no field 'preset' at the top level"),
    ("sweep.lab_weights=1,2", "expected 3 comma-separated values"),
    ("sweep.blur=nan", "NaN is not a setting"),
    ("sweep.window=8", "must be an odd number"),
    ("aggregate.splat_step=0", "grid step must be 1"),
])
def test_a_bad_setting_is_one_line_naming_it(setting, expect):
    with pytest.raises(ValueError) as e:
        get_preset("default").with_settings([setting])
    msg = str(e.value)
    assert expect in msg and setting in msg and "\n" not in msg


def test_the_plane_cue_is_on_only_where_the_map_adds_it():
    """Params.plane_cue: a weight and the depth-consistent fusion; Eq. 3's sum (paper) and the
    peer's own map take none, whatever the weight says."""
    assert get_preset("default").plane_cue
    assert not get_preset("default").with_settings(["aggregate.plane_weight=0"]).plane_cue
    assert not get_preset("paper").plane_cue
    assert not get_preset("paper").with_settings(["aggregate.plane_weight=0.6"]).plane_cue
    assert not get_preset("peer-homography").with_settings(["aggregate.plane_weight=0.6"]).plane_cue
