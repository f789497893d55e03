"""Calibration: recover known parameters from synthetic observations with noise."""
import json
from pathlib import Path

import numpy as np
import pytest

from softsnap_model import Skeleton
from softsnap_model.calibration import (Observation, calibrate, load_observations,
                                        observations_to_dict, synthetic_observations)
from softsnap_model.cli import main
from softsnap_model.reference import PAPER_THREADINGS

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / 'docs' / 'examples' / 'calibration_example.yaml'
GEOMETRY = dict(n_ribs=12, spacing_mm=18.0, rib_length_mm=25.0)
SK = Skeleton(**GEOMETRY)
THREE = [PAPER_THREADINGS['yellow'], PAPER_THREADINGS['red'], PAPER_THREADINGS['blue']]


@pytest.mark.slow
def test_recovers_stiffness_friction_and_encoder_scale_within_ci():
    rng = np.random.default_rng(1)
    k_true = np.round(rng.uniform(0.7, 1.4, 11), 3)
    k_true[0] = 1.0
    truth = Skeleton(**GEOMETRY, stiffness=list(k_true))
    obs = synthetic_observations(truth, THREE, [15, 30, 45], friction=0.15,
                                 length_scale=1.02, length_offset_mm=-1.5, noise_mm=0.2,
                                 seed=3)
    res = calibrate(SK, obs)
    assert res.converged, res.message
    expected = list(k_true[1:]) + [0.15, 1.02, -1.5]
    assert list(res.names) == [f'stiffness[{i}]' for i in range(1, 11)] + \
        ['friction', 'length_scale', 'length_offset_mm']
    inside = (res.ci_low <= expected) & (expected <= res.ci_high)
    # 13 95% intervals: all inside is likely; allow one miss.
    assert inside.sum() >= 12, list(zip(res.names, res.values, expected))
    assert abs(res.friction - 0.15) < 0.01
    assert np.all(res.stderr > 0) and np.all(np.isfinite(res.stderr))
    # The fitted RMSE estimates the marker noise (0.2 mm per coordinate).
    assert 0.15 <= res.rmse_mm <= 0.25
    assert res.stiffness[0] == 1.0 and res.skeleton.stiffness[3] == pytest.approx(
        res.stiffness[3])


def test_noise_free_data_give_the_parameters_exactly():
    obs = synthetic_observations(SK, THREE[:2], [20, 40], friction=0.2, length_scale=0.98,
                                 length_offset_mm=2.0)
    res = calibrate(SK, obs, fit=('friction', 'length_scale', 'length_offset'))
    assert res.converged
    assert res.values == pytest.approx([0.2, 0.98, 2.0], abs=1e-6)
    assert res.rmse_mm < 1e-6


def test_release_observations_and_missing_markers():
    obs = synthetic_observations(SK, THREE[:1], [25, 45], friction=0.12, noise_mm=0.1,
                                 seed=11, directions=('pull', 'release'))
    pts = obs[0].rib_centers_mm.copy()
    pts[5] = np.nan                       # a marker not seen
    obs[0] = Observation(obs[0].threading, obs[0].cable_length_mm, pts, 'pull')
    res = calibrate(SK, obs, fit=('friction',))
    assert res.converged
    assert res.ci_low[0] <= 0.12 <= res.ci_high[0]
    assert res.n_points == 4 * 11 - 1


def test_friction_fixed_when_not_fitted():
    obs = synthetic_observations(SK, THREE[:1], [20, 35], length_scale=1.01)
    res = calibrate(SK, obs, fit=('length_scale',))
    assert res.friction == 0.0 and res.values[0] == pytest.approx(1.01, abs=1e-6)


def test_bad_input():
    obs = synthetic_observations(SK, THREE[:1], [20])
    with pytest.raises(ValueError, match='unknown'):
        calibrate(SK, obs, fit=('stifness',))
    with pytest.raises(ValueError, match='reference_segment'):
        calibrate(SK, obs, reference_segment=11)
    with pytest.raises(ValueError, match='at least one'):
        calibrate(SK, [])
    few = obs[0].rib_centers_mm.copy()
    few[4:] = np.nan                      # 3 markers: 6 residuals for 13 parameters
    with pytest.raises(ValueError, match='need more observations'):
        calibrate(SK, [Observation(THREE[0], obs[0].cable_length_mm, few)])
    with pytest.raises(ValueError, match='direction'):
        Observation(THREE[0], 150.0, np.zeros((12, 2)), 'sideways')
    with pytest.raises(ValueError, match='cable_length_mm'):
        Observation(THREE[0], float('nan'), np.zeros((12, 2)))
    bad = Observation(THREE[0], 150.0, np.zeros((11, 2)))
    with pytest.raises(ValueError, match='expected 12 rib centres'):
        calibrate(SK, [bad], fit=('friction',))


def test_file_round_trip(tmp_path):
    obs = synthetic_observations(SK, THREE[:1], [20], friction=0.1, noise_mm=0.1)
    path = tmp_path / 'obs.json'
    path.write_text(json.dumps(observations_to_dict(obs, SK)))
    sk, back = load_observations(path)
    assert sk == SK and len(back) == 1
    assert np.allclose(back[0].rib_centers_mm, obs[0].rib_centers_mm, atol=1e-4)
    path.write_text(json.dumps({'observations': [{'threading': 'R1'}]}))
    with pytest.raises(ValueError, match='missing key'):
        load_observations(path)
    path.write_text(json.dumps({'observation': []}))
    with pytest.raises(ValueError, match='observations'):
        load_observations(path)


def test_cli_calibrate_example_file(capsys):
    code = main(['calibrate', '--data', str(EXAMPLE), '--fit',
                 'friction,length_scale,length_offset'])
    out = capsys.readouterr()
    assert code == 0, out.err
    data = json.loads(out.out)
    p = data['parameters']
    assert set(p) == {'friction', 'length_scale', 'length_offset_mm'}
    # The example was generated with friction 0.15, scale 1.02, offset -1.5 mm and
    # 0.3 mm noise; its stiffness differs from the fit's (all 1), so allow a margin.
    assert abs(p['friction']['value'] - 0.15) < 0.05
    assert p['friction']['ci_low'] < p['friction']['value'] < p['friction']['ci_high']
    assert 0.0 < data['rmse_mm'] < 3.0 and data['n_observations'] == 4


def test_cli_calibrate_bad_file(capsys, tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('observations: 3\n')
    assert main(['calibrate', '--data', str(path)]) == 2
    assert 'observations' in json.loads(capsys.readouterr().err)['error']


def test_recovers_bending_stiffness_from_shapes_under_gravity():
    # A module lying on its side (gravity in its plane) sags by an amount set by K: shapes
    # made with a known K plus 0.2 mm marker noise give K back within its interval.
    from softsnap_model.loads import DEFAULT_BENDING_STIFFNESS_NMM
    true_k = 30.0
    obs = synthetic_observations(SK, [PAPER_THREADINGS['yellow'], PAPER_THREADINGS['green']],
                                 [10.0, 25.0, 40.0], gravity_mps2=(0.0, -9.81, 0.0),
                                 bending_stiffness_nmm=true_k, noise_mm=0.2, seed=3)
    assert all(o.loaded for o in obs)
    res = calibrate(SK, obs, fit=('bending_stiffness',),
                    initial={'bending_stiffness': DEFAULT_BENDING_STIFFNESS_NMM})
    assert res.converged, res.message
    assert res.names == ('bending_stiffness_nmm',)
    assert res.ci_low[0] < true_k < res.ci_high[0], (res.values, res.ci_low, res.ci_high)
    assert res.bending_stiffness_nmm == pytest.approx(true_k, rel=0.05)
    assert res.ci_high[0] - res.ci_low[0] < 0.2 * true_k       # the data pin K down
    assert 0.1 < res.rmse_mm < 0.3                              # the noise, no model error
    # The sag really is K's signature: the start value fits far worse.
    start = calibrate(SK, obs, fit=('length_offset',),
                      initial={'bending_stiffness': DEFAULT_BENDING_STIFFNESS_NMM})
    assert start.rmse_mm > 5 * res.rmse_mm


def test_bending_stiffness_needs_loaded_observations_and_no_friction():
    plain = synthetic_observations(SK, [PAPER_THREADINGS['yellow']], [20.0, 40.0])
    with pytest.raises(ValueError, match='needs observations under gravity or a load'):
        calibrate(SK, plain, fit=('bending_stiffness',))
    loaded = synthetic_observations(SK, [PAPER_THREADINGS['yellow']], [20.0, 40.0],
                                    gravity_mps2=(0.0, -9.81, 0.0))
    with pytest.raises(ValueError, match='without friction'):
        calibrate(SK, loaded, fit=('bending_stiffness', 'friction'))
    with pytest.raises(ValueError, match='load_rib'):
        Observation(PAPER_THREADINGS['yellow'], 150.0, np.zeros((12, 2)), load_rib=0)


def test_loaded_observations_round_trip_through_a_file(tmp_path):
    import yaml
    from softsnap_model.calibration import observations_to_dict
    obs = synthetic_observations(SK, [PAPER_THREADINGS['yellow']], [20.0],
                                 load_n=(0.0, -0.05, 0.0), bending_stiffness_nmm=25.0)
    path = tmp_path / 'loaded.yaml'
    path.write_text(yaml.safe_dump(observations_to_dict(obs, SK)))
    _, back = load_observations(path)
    assert back[0].load_n == (0.0, -0.05, 0.0) and back[0].loaded
    np.testing.assert_allclose(back[0].rib_centers_mm, obs[0].rib_centers_mm, atol=1e-4)
