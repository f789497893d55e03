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


# -- boundaries and refusals that mutation testing showed unchecked (docs/testing.md) ----
from fractions import Fraction  # noqa: E402

from softsnap_driver.core import RANGE_TOL_M  # noqa: E402


def exact_count_range(counts_per_mm: str, min_mm_m: str, max_mm_m: str, sign: int = 1):
    """The allowed counts from the decimal values as written (exact rational arithmetic)."""
    per_m = Fraction(counts_per_mm) * 1000
    low = math.ceil(Fraction(min_mm_m) * per_m)
    high = math.floor(Fraction(max_mm_m) * per_m)
    return (low, high) if sign > 0 else (-high, -low)


@pytest.mark.parametrize('sign', [1, -1])
def test_count_range_is_exact_where_float_products_miss_whole_counts(sign):
    # 0.0083 m x 1000 x 100 counts/mm is 830.0000000000001 in floats, 0.0373 m gives
    # 3729.9999999999995: without rounding towards the inside the range would lose a
    # count at each end; rounding the wrong way would let the winch pass the limit.
    cal = CableCalibration(counts_per_mm=100.0, straight_length_m=0.2, max_contraction_m=0.0373,
                           min_contraction_m=0.0083, count_sign=sign)
    assert cal.count_range == exact_count_range('100', '0.0083', '0.0373', sign) \
        == ((830, 3730) if sign > 0 else (-3730, -830))
    low_len, high_len = cal.length_range_m
    assert (low_len, high_len) == pytest.approx((0.2 - 0.0373, 0.2 - 0.0083), abs=1e-15)
    far, near = sorted(cal.count_range, key=abs, reverse=True)
    assert cal.command(low_len).count == far and cal.command(high_len).count == near
    assert cal.command(0.19).count == sign * 1000
    assert cal.length_m(sign * 1000) == pytest.approx(0.19, abs=1e-15)


@pytest.mark.parametrize('min_contraction_m', [-1e-9, -0.001, math.nan, -math.inf, math.inf])
def test_negative_or_non_finite_min_contraction_is_refused(min_contraction_m):
    # A negative minimum would let the winch pay out cable beyond the calibrated straight length.
    with pytest.raises(ValueError, match='^min_contraction_m must be >= 0'):
        CableCalibration(counts_per_mm=100.0, straight_length_m=0.2, max_contraction_m=0.05,
                         min_contraction_m=min_contraction_m)


@pytest.mark.parametrize('kwargs, name', [
    (dict(counts_per_mm=-89.13), 'counts_per_mm must be'),
    (dict(counts_per_mm=math.inf), 'counts_per_mm must be'),
    (dict(counts_per_mm=True), 'counts_per_mm must be'),          # a bool is not a calibration
    (dict(straight_length_m=0.0), 'straight_length_m must be positive'),
    (dict(straight_length_m=math.inf), 'straight_length_m must be'),
    (dict(straight_length_m=False), 'straight_length_m must be'),
    (dict(max_contraction_m=math.nan), 'max_contraction_m must be'),
    (dict(max_contraction_m=0.198), 'max_contraction_m must be'),  # the whole cable
    (dict(max_contraction_m=-0.001), 'max_contraction_m must be'),
    (dict(max_contraction_m=True), 'max_contraction_m must be'),
    (dict(min_contraction_m=True), 'min_contraction_m must be'),
    (dict(clamp_margin_m=True), 'clamp_margin_m must be'),
    (dict(clamp_margin_m='0.001'), 'clamp_margin_m must be'),
    (dict(count_sign=True), 'count_sign must be'),                # True == 1 but is not a sign
    (dict(count_sign=2), 'count_sign must be'),
    (dict(count_sign=1.0), 'count_sign must be'),
    (dict(counts_per_mm=0.01, max_contraction_m=0.0004, min_contraction_m=0.0003),
     r'the contraction range \[0.0003, 0.0004\] m holds no whole encoder count'),
])
def test_more_bad_calibrations_are_refused(kwargs, name):
    values = dict(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.08)
    values.update(kwargs)
    with pytest.raises(ValueError, match=f'^{name}'):   # the check that names the value
        CableCalibration(**values)


def test_limits_of_a_valid_calibration_are_accepted():
    # Each boundary of the checks above on its accepted side.
    CableCalibration(counts_per_mm=100.0, straight_length_m=0.198, max_contraction_m=0.08,
                     min_contraction_m=0.08, clamp_margin_m=1.0)
    CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.0,
                     clamp_margin_m=0, count_sign=-1)
    single = CableCalibration(counts_per_mm=0.5, straight_length_m=0.2, max_contraction_m=0.002,
                              min_contraction_m=0.002)
    assert single.count_range == (1, 1)


@pytest.mark.parametrize('length_m', [True, False, '0.19', None, b'0.19', [0.19]])
def test_command_that_is_not_a_number_is_refused(length_m):
    with pytest.raises(ValueError, match='must be a number in metres'):
        CAL.command(length_m)


@pytest.mark.parametrize('length_m, message', [(math.nan, 'finite'), (math.inf, 'finite'),
                                               (-math.inf, 'finite'), (0, '> 0 m')])
def test_command_refusals_name_the_reason(length_m, message):
    with pytest.raises(ValueError, match=message):
        CAL.command(length_m)


def test_int_command_is_taken_in_metres():
    cal = CableCalibration(counts_per_mm=100.0, straight_length_m=1.5, max_contraction_m=0.8)
    assert cal.command(1).count == 50000 and cal.command(1).requested_length_m == 1.0


def test_clamp_margin_boundaries_are_inclusive():
    cal = CableCalibration(counts_per_mm=100.0, straight_length_m=0.2, max_contraction_m=0.05,
                           clamp_margin_m=0.004)
    shortest, longest = cal.length_range_m
    margin = 0.004 + RANGE_TOL_M
    for edge, outward in ((shortest - margin, -math.inf), (longest + margin, math.inf)):
        assert cal.command(edge).clamped                        # exactly at the margin: clamped
        with pytest.raises(ValueError, match='clamp_margin_m=0.004'):
            cal.command(math.nextafter(edge, outward))          # one float beyond: refused
    for edge, outward in ((shortest - RANGE_TOL_M, -math.inf), (longest + RANGE_TOL_M, math.inf)):
        assert not cal.command(edge).clamped                    # within the tolerance: not clamped
        assert cal.command(math.nextafter(edge, outward)).clamped
    assert [cal.command(x).count for x in (shortest - 0.003, longest + 0.003)] == [5000, 0]
    cmd = cal.command(longest + 0.003)
    assert cmd.length_m == longest and cmd.requested_length_m == longest + 0.003


def test_reboot_evidence_boundaries():
    # Each threshold on both sides (REBOOT: zero band 60, jump 300, 12000 counts/s).
    assert reboot_suspected(3000, 0, 60, 0, 0.1, 3000, **REBOOT)          # at the zero band
    assert reboot_suspected(3000, 0, -60, 0, 0.1, 3000, **REBOOT)
    assert reboot_suspected(3000, 0, 61, 0, 0.1, 3000, **REBOOT) is None
    assert reboot_suspected(300, 0, 0, 0, 0.1, 3000, **REBOOT)            # at the jump size
    assert reboot_suspected(-300, 0, 0, 0, 0.1, 3000, **REBOOT)
    assert reboot_suspected(299, 0, 0, 0, 0.1, 3000, **REBOOT) is None
    assert reboot_suspected(3000, 0, 0, 0, 0.1, 61, **REBOOT)             # target out of the band
    assert reboot_suspected(3000, 0, 0, 0, 0.1, -61, **REBOOT)
    # Driven home: the target inside the zero band; the jump at exactly the top speed is legal.
    assert reboot_suspected(1200, 0, 0, 0, 0.1, 60, **REBOOT) is None
    assert reboot_suspected(1200, 0, 0, 0, 0.1, -60, **REBOOT) is None
    assert 'faster than 12000 counts/s' in reboot_suspected(1201, 0, 0, 0, 0.1, 0, **REBOOT)
    assert reboot_suspected(1200, 0, 30, 0, 0.1, 0, **REBOOT) is None
    assert reboot_suspected(-1200, 0, 30, 0, 0.1, 0, **REBOOT)            # 1230 counts in 0.1 s
    assert reboot_suspected(3000, 0, 0, 0, -1.0, 0, **REBOOT)             # clock went back: no time
    assert reboot_suspected(3000, 5, 3000, 5, 0.1, 3000, **REBOOT) is None   # errors unchanged
    assert 'from 5 to 4' in reboot_suspected(3000, 5, 3000, 4, 0.1, 3000, **REBOOT)
    assert 'target was unknown' in reboot_suspected(3000, 0, 0, 0, 0.1, None, **REBOOT)
    assert 'target was 3000' in reboot_suspected(3000, 0, 0, 0, 0.1, 3000, **REBOOT)


def test_calibration_and_commands_are_immutable():
    # count_range and length_range_m are cached: a calibration changed in place would
    # keep clamping to the old range.
    import dataclasses
    with pytest.raises(dataclasses.FrozenInstanceError):
        CAL.max_contraction_m = 0.15
    with pytest.raises(dataclasses.FrozenInstanceError):
        CAL.command(0.19).count = 7000
