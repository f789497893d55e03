"""Length <-> count conversion, clamping and reboot detection (pure core)."""
import math

import pytest

from softsnap_driver.core import CableCalibration, reboot_suspected

CAL = CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.080)


@pytest.mark.parametrize('length_m, count', [
    (0.198, 0),                 # straight: count 0
    (0.188, 891),               # 10 mm contraction: 891.3 counts, rounded
    (0.118, 7130),              # 80 mm: the far end (7130.4 rounded into the range)
])
def test_length_to_count_known_answers(length_m, count):
    cmd = CAL.command(length_m)
    assert cmd.count == count and not cmd.clamped
    assert CAL.length_m(cmd.count) == pytest.approx(length_m, abs=1 / 89.13 / 1000)


@pytest.mark.parametrize('length_m, count', [
    (0.2009, 0), (0.1171, 7130),        # within clamp_margin_m (5 mm) of the range
    (0.203, 0), (0.113 + 1e-6, 7130),
])
def test_near_range_commands_are_clamped_inside(length_m, count):
    cmd = CAL.command(length_m)
    assert cmd.clamped and cmd.count == count
    low, high = CAL.length_range_m
    assert low - 1e-12 <= cmd.length_m <= high + 1e-12


@pytest.mark.parametrize('length_m', [
    0.0,                        # regression: a default-constructed CableLength was driven to full contraction
    -0.0, -5.0, 5e-324, 0.30, 0.2031, 0.1129, 1e300, 1.7e308, -1.7e308,
])
def test_non_physical_commands_are_refused_with_the_range(length_m):
    with pytest.raises(ValueError, match=r'> 0 m|outside the allowed range \[0\.118000, 0\.198000\]'):
        CAL.command(length_m)


def test_clamp_margin_is_a_parameter():
    strict = CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.080,
                              clamp_margin_m=0.0)
    assert not strict.command(0.198).clamped
    with pytest.raises(ValueError, match='clamp_margin_m=0'):
        strict.command(0.1985)
    for bad in (-0.001, math.nan, math.inf, 2.0):
        with pytest.raises(ValueError, match='clamp_margin_m'):
            CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.080,
                             clamp_margin_m=bad)


def test_count_range_never_exceeds_the_contraction_range():
    cal = CableCalibration(counts_per_mm=33.3, straight_length_m=0.2, max_contraction_m=0.0501,
                           min_contraction_m=0.0049)
    low, high = cal.count_range
    assert low / 33.3 >= 4.9 - 1e-9 and high / 33.3 <= 50.1 + 1e-9
    assert cal.command(0.2).count == low and cal.command(0.149).count == high


def test_negative_count_sign():
    cal = CableCalibration(counts_per_mm=100.0, straight_length_m=0.2, max_contraction_m=0.05,
                           count_sign=-1)
    assert cal.command(0.19).count == -1000
    assert cal.count_range == (-5000, 0)
    assert cal.length_m(-1000) == pytest.approx(0.19)


@pytest.mark.parametrize('kwargs, name', [
    (dict(counts_per_mm=0.0), 'counts_per_mm'),
    (dict(counts_per_mm=math.nan), 'counts_per_mm'),
    (dict(straight_length_m=-1.0), 'straight_length_m'),
    (dict(max_contraction_m=0.5), 'max_contraction_m'),
    (dict(min_contraction_m=0.09), 'max_contraction_m'),
    (dict(count_sign=0), 'count_sign'),
])
def test_bad_calibration_is_refused_naming_the_value(kwargs, name):
    values = dict(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.08)
    values.update(kwargs)
    with pytest.raises(ValueError, match=name):
        CableCalibration(**values)


REBOOT = dict(zero_band_counts=60, min_jump_counts=300, max_speed_counts_per_s=12000.0)


def test_reboot_detected_when_count_resets_away_from_target():
    assert reboot_suspected(3000, 0, 0, 0, 0.1, 3000, **REBOOT)
    assert reboot_suspected(3000, 0, 5, 0, 30.0, None, **REBOOT)       # never commanded home


def test_reboot_detected_when_error_counter_falls():
    assert 'error counter' in reboot_suspected(1000, 12, 1010, 0, 0.1, 1000, **REBOOT)


def test_reboot_detected_when_return_home_is_too_fast():
    assert reboot_suspected(6000, 0, 0, 0, 0.1, 0, **REBOOT)            # 60000 counts/s


def test_legitimate_moves_are_not_reboots():
    assert reboot_suspected(3000, 0, 30, 0, 0.5, 0, **REBOOT) is None   # driven home at 6000/s
    assert reboot_suspected(200, 0, 0, 0, 0.1, 3000, **REBOOT) is None  # small counts
    assert reboot_suspected(3000, 0, 2900, 0, 0.1, 3000, **REBOOT) is None
    assert reboot_suspected(3000, 3, 3000, 5, 0.1, 3000, **REBOOT) is None
