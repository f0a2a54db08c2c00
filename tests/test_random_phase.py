"""Philox4x32-10 phases on the device against the NumPy reference, bit for bit."""

import numpy as np
import pytest

from clholo import reference
from clholo.random import philox4x32_10, random_phases

from tolerances import tol

# HOLOGRAPHY.md section 4 known answers (Random123 test vectors)
KNOWN_ANSWERS = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


def test_known_answers_reference():
    for ctr, key, want in KNOWN_ANSWERS:
        got = reference.philox4x32_10([np.uint32(c) for c in ctr], [np.uint32(k) for k in key])
        assert tuple(int(w) for w in got) == want


def test_known_answers_device(queue):
    counters = np.array([c for c, _, _ in KNOWN_ANSWERS], np.uint32)
    keys = np.array([k for _, k, _ in KNOWN_ANSWERS], np.uint32)
    got = philox4x32_10(counters, keys, queue=queue)
    np.testing.assert_array_equal(got, np.array([w for _, _, w in KNOWN_ANSWERS], np.uint32))


def test_raw_stream_matches_reference_random_counters(queue, rng):
    counters = rng.integers(0, 2 ** 32, size=(4096, 4), dtype=np.uint64).astype(np.uint32)
    keys = rng.integers(0, 2 ** 32, size=(4096, 2), dtype=np.uint64).astype(np.uint32)
    got = philox4x32_10(counters, keys, queue=queue)
    want = np.stack(reference.philox4x32_10(counters.T, keys.T), axis=1)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (17, 31), (64, 64), (127, 200)])
def test_phases_bit_for_bit(queue, rng, shape):
    assert tol("random_phase", np.float32)["max_abs"] == 0.0
    seed = int(rng.integers(0, 2 ** 63))
    layer = int(rng.integers(0, 64))
    got = random_phases(shape, seed=seed, layer=layer, frames=3, colours=2, frame0=5,
                        queue=queue).get()
    for f in range(3):
        for c in range(2):
            want = reference.random_phase(shape, seed=seed, frame=5 + f, colour=c, layer=layer)
            assert got[f, c].view(np.uint32).tolist() == want.view(np.uint32).tolist()


def test_phases_statistics_and_independence(queue):
    phi = random_phases((256, 256), seed=12345, layer=3, frames=2, colours=1, queue=queue).get()
    assert phi.min() >= 0.0 and phi.max() <= np.float32(2 * np.pi)
    # uniform: mean pi, variance (2 pi)^2 / 12, to a few standard errors of 65536 samples
    assert abs(phi[0, 0].mean() - np.pi) < 0.02
    assert abs(phi[0, 0].var() - (2 * np.pi) ** 2 / 12) < 0.05
    # frames are independent draws: correlation of exp(i phi) near zero
    corr = np.mean(np.exp(1j * phi[0, 0]) * np.exp(-1j * phi[1, 0]))
    assert abs(corr) < 0.02


def test_seed_changes_stream(queue):
    a = random_phases((32, 32), seed=1, layer=0, queue=queue).get()
    b = random_phases((32, 32), seed=2, layer=0, queue=queue).get()
    c = random_phases((32, 32), seed=1 + 2 ** 32, layer=0, queue=queue).get()  # high key word
    assert np.mean(a != b) > 0.99 and np.mean(a != c) > 0.99


def test_bad_arguments(queue):
    with pytest.raises(ValueError, match="seed"):
        random_phases((4, 4), seed=-1, layer=0, queue=queue)
    with pytest.raises(ValueError, match="layer"):
        random_phases((4, 4), seed=0, layer=2 ** 32, queue=queue)
    with pytest.raises(ValueError, match="shape"):
        random_phases((0, 4), seed=0, layer=0, queue=queue)
