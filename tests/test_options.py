"""One way to say each setting: the settings dataclasses are the truth, the
command line's options are generated from their fields, and clpt.render
hands each keyword to the one place that takes it."""

import dataclasses

import numpy as np
import pytest

import clpt
from clpt import options
from clpt.cli import build_parser
from clpt.cli.render import _adaptive_settings, _filter_settings, _photon_settings


def parse(*args):
    return build_parser().parse_args(["render", "cornell_box", *args])


@pytest.mark.parametrize("cls, opts", options.GROUPS)
def test_every_option_names_a_field_and_states_its_default_from_the_dataclass(cls, opts):
    names = {f.name for f in dataclasses.fields(cls)}
    for o in opts:
        assert o.field in names, o.flag
        text = options.help_text(cls, o)
        d = options.field_default(cls, o.field)
        if o.show_default and not o.is_switch() and d is not None:
            assert text.endswith(f"(default {options._format_default(d)})"), o.flag
        assert "{" not in text, o.flag


def test_a_changed_default_changes_the_help(monkeypatch):
    opt = next(o for o in options.PHOTON_OPTIONS if o.flag == "--alpha")
    before = options.help_text(clpt.PhotonSettings, opt)
    f = next(f for f in dataclasses.fields(clpt.PhotonSettings) if f.name == "alpha")
    monkeypatch.setattr(f, "default", 0.55)
    assert before.endswith("(default 0.7)") and options.help_text(clpt.PhotonSettings, opt).endswith("(default 0.55)")
    # The photon count's help names photons_per_sample's default.
    count = next(o for o in options.PHOTON_OPTIONS if o.flag == "--photons")
    assert f"{clpt.PhotonSettings.photons_per_sample:g} per camera sample" in options.help_text(clpt.PhotonSettings,
                                                                                                   count)


def test_options_not_given_leave_the_dataclass_defaults():
    a = parse()
    assert _photon_settings(a) == clpt.PhotonSettings().check()
    assert _adaptive_settings(parse("--adaptive", "error")) == clpt.AdaptiveSettings(scheme="error")
    assert _filter_settings(parse("--filter")) == clpt.FilterSettings()


def test_given_options_set_their_fields():
    a = parse("--radius", "0.01", "--radius-absolute", "--no-photon-pilot", "--photon-mode", "online",
              "--spp-per-map", "4")
    p = _photon_settings(a)
    assert (p.radius, p.radius_absolute, p.pilot, p.mode, p.spp_per_map) == (0.01, True, False, "online", 4)
    ad = _adaptive_settings(parse("--adaptive", "paper", "--paper-stop", "--no-depth-reduction", "--min-spp", "8"))
    assert (ad.paper_mode, ad.reduce_depth, ad.min_spp) == ("stop", False, 8)
    f = _filter_settings(parse("--denoise", "cone", "--filter-width", "2", "--filter-interval", "3"))
    assert (f.width, f.interval) == (2, 3)


def test_options_of_the_other_denoiser_are_refused():
    with pytest.raises(clpt.SettingsError, match="--filter-width"):
        _filter_settings(parse("--denoise", "oidn", "--filter-width", "2"))
    with pytest.raises(clpt.SettingsError, match="--oidn-aux"):
        _filter_settings(parse("--filter", "--oidn-aux", "noisy"))


def test_bad_settings_raise_settings_errors():
    for bad in (lambda: clpt.PhotonSettings(alpha=2.0).check(), lambda: clpt.AdaptiveSettings(min_spp=0).check(),
                lambda: clpt.FilterSettings(width=99).check()):
        with pytest.raises(clpt.SettingsError):
            bad()
    assert issubclass(clpt.SettingsError, clpt.SceneError)


def test_photon_settings_on_the_renderer_are_its_renders_default(device_spec):
    ph = clpt.PhotonSettings(count=5000, progressive=False, pilot=False)
    r = clpt.Renderer("cornell_box_caustics", device=device_spec, photons=ph)
    a = r.render(2, width=16, height=16, seed=3)
    b = clpt.Renderer("cornell_box_caustics", device=device_spec).render(2, width=16, height=16, seed=3, photons=ph)
    assert a.photons == b.photons and np.array_equal(a.image, b.image)
    # clpt.render gives each keyword to the one that takes it.
    img = clpt.render("cornell_box_caustics", spp=2, width=16, height=16, seed=3, photons=ph, device=device_spec)
    assert np.array_equal(img, a.image)
    with pytest.raises(TypeError, match="colour"):
        clpt.render("cornell_box", spp=1, colour="red")
