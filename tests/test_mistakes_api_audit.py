"""User mistakes at the Python API found by an audit (2026-11-29): each was a silent wrong
result, a file clholo wrote but could not read back, or an error from deep inside NumPy or
pyopencl; each is now refused by name, or works."""

import numpy as np
import pytest

from clholo.errors import EnvironmentProblem, ExitCode, InputError, InputTypeError
from clholo.scene import MPI, Optics


def _rgb(seed=0, shape=(16, 16)):
    rng = np.random.default_rng(seed)
    image = (rng.random(shape + (3,)) * 255).astype(np.uint8)
    depth = rng.random(shape) + 0.5
    return image, depth


# rgbd_to_mpi: integer colour is 8- or 16-bit codes, nothing else

@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.int16, np.uint32])
def test_rgbd_integer_colour_other_than_codes_is_refused(dtype):
    """0..255 in an int64 array (NumPy's default for a list of ints) was divided by int64's
    largest value: a black scene (colour 2e-18) without a word."""
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    with pytest.raises(InputError, match=rf"image holds {np.dtype(dtype).name} values .*"
                                         r"astype\(np\.uint8\)"):
        rgbd_to_mpi(image.astype(dtype), depth, layers=4, near=2e-3, far=5e-3)


def test_rgbd_signed_colour_with_negatives_is_refused():
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    with pytest.raises(InputError, match=r"int8 values \(-\d+\.\.\d+\).*floats in \[0, 1\]"):
        rgbd_to_mpi((image.astype(np.int16) - 128).astype(np.int8), depth, layers=4,
                    near=2e-3, far=5e-3)


def test_rgbd_eight_bit_codes_in_a_sixteen_bit_array_are_refused():
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    with pytest.raises(InputError, match=r"uint16 but its values lie in 0\.\.\d+"):
        rgbd_to_mpi(image.astype(np.uint16), depth, layers=4, near=2e-3, far=5e-3)


def test_rgbd_codes_of_both_widths_give_the_same_scene():
    """The two code widths stay accepted, and mean the same colour (255 * 257 = 65535)."""
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    m8 = rgbd_to_mpi(image, depth, layers=4, near=2e-3, far=5e-3)
    m16 = rgbd_to_mpi(image.astype(np.uint16) * 257, depth, layers=4, near=2e-3, far=5e-3)
    np.testing.assert_allclose(m16.color, m8.color, rtol=0, atol=1e-6)
    assert float(m8.color.max()) > 0.5


@pytest.mark.parametrize("option", ["zero_is_invalid", "srgb"])
def test_rgbd_flags_must_be_bools(option):
    """``zero_is_invalid="no"`` was taken as True."""
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    with pytest.raises(InputTypeError, match=rf"{option} must be True or False, got 'no'"):
        rgbd_to_mpi(image, depth, layers=4, near=2e-3, far=5e-3, **{option: "no"})


@pytest.mark.parametrize("which", ["image", "depth"])
def test_rgbd_paths_instead_of_arrays_say_to_read_the_file(which):
    from clholo.io import rgbd_to_mpi

    image, depth = _rgb()
    args = {"image": image, "depth": depth}
    args[which] = f"{which}.png"
    with pytest.raises(InputTypeError, match=rf"{which} must be an array .*the path "
                                             rf"'{which}\.png': read the file first"):
        rgbd_to_mpi(args["image"], args["depth"], layers=4, near=2e-3, far=5e-3)


def test_rgbd_empty_image_is_named():
    from clholo.io import rgbd_to_mpi

    with pytest.raises(InputError, match=r"image is empty \(shape \(0, 0, 3\)\)"):
        rgbd_to_mpi(np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0)), layers=4, near=2e-3,
                    far=5e-3)


# write_hologram: what it writes, read_hologram reads

@pytest.mark.parametrize("kwargs, error, match", [
    ({"wavelengths": (638, 520, 450)}, InputError, r"wavelengths=638 is not a wavelength in "
                                                   r"metres"),
    ({"wavelengths": (0.638, 0.52, 0.45)}, InputError, "wavelength"),
    ({"wavelengths": (638e-9, float("nan"), 450e-9)}, InputError, "wavelengths"),
    ({"pitch": 8e-9}, InputError, r"below 0\.1 um, half the shortest wavelength"),
    ({"pitch": 3e-7}, InputError, "twice the pitch"),
    ({"pitch": "abc"}, InputTypeError, "pitch must be a real number"),
    ({"seed": 1.5}, InputTypeError, "seed must be an integer .*truncated"),
    ({"seed": "7"}, InputTypeError, "seed must be an integer"),
    ({"seed": True}, InputTypeError, "seed must be an integer"),
])
def test_write_hologram_refuses_what_read_hologram_would(tmp_path, kwargs, error, match):
    from clholo.io import write_hologram

    args = {"pitch": 8e-6, "wavelengths": (638e-9, 520e-9, 450e-9)}
    args.update(kwargs)
    path = tmp_path / "h.npz"
    with pytest.raises(error, match=match):
        write_hologram(path, np.ones((1, 3, 8, 8), np.complex64), **args)
    assert list(tmp_path.iterdir()) == []  # nothing written, not even a temporary


def test_write_hologram_refuses_an_empty_field(tmp_path):
    from clholo.io import write_hologram

    with pytest.raises(InputError, match=r"field is empty \(shape \(0, 3, 8, 8\)\)"):
        write_hologram(tmp_path / "h.npz", np.ones((0, 3, 8, 8), np.complex64), pitch=8e-6,
                       wavelengths=(638e-9, 520e-9, 450e-9))


@pytest.mark.parametrize("suffix", [".npz", ".exr"])
def test_write_hologram_round_trip_still_exact(tmp_path, suffix):
    from clholo.io import read_hologram, write_hologram

    rng = np.random.default_rng(3)
    field = (rng.standard_normal((2, 3, 8, 8)) + 1j * rng.standard_normal((2, 3, 8, 8))
             ).astype(np.complex64)
    path = write_hologram(tmp_path / f"h{suffix}", field, pitch=8e-6,
                          wavelengths=(638e-9, 520e-9, 450e-9), seed=np.uint64(2 ** 63))
    back, meta = read_hologram(path)
    assert np.array_equal(back, field) and meta["seed"] == 2 ** 63


# write_mpi / read_mpi: any number of colour channels round-trips

@pytest.mark.parametrize("channels", [1, 2, 3, 4, 5])
def test_mpi_of_any_channel_count_reads_back_exactly(tmp_path, channels):
    """A 2- or 4-channel MPI was written as EXR layers (c0 .. cN, A) that read_mpi refused:
    'has no alpha channel'."""
    from clholo.io import read_mpi, write_mpi

    rng = np.random.default_rng(channels)
    m = MPI(rng.random((3, 8, 8, channels)), rng.random((3, 8, 8)), [2e-3, 3e-3, 4e-3])
    back = read_mpi(write_mpi(tmp_path / "m", m))
    assert back.color.shape == m.color.shape
    assert np.array_equal(back.color, m.color) and np.array_equal(back.alpha, m.alpha)


def test_write_mpi_overwrite_must_be_a_bool(tmp_path):
    """``overwrite="yes"`` replaced the folder as True would."""
    from clholo.io import write_mpi

    rng = np.random.default_rng(0)
    m = MPI(rng.random((2, 8, 8, 1)), rng.random((2, 8, 8)), [2e-3, 3e-3])
    write_mpi(tmp_path / "m", m)
    with pytest.raises(InputTypeError, match="overwrite must be True or False, got 'no'"):
        write_mpi(tmp_path / "m", m, overwrite="no")


# sizes: whole numbers, not whatever int() makes of them

@pytest.mark.parametrize("shape", [(8.5, 8), (True, 8), "8x8", (8, None)])
def test_fft_plan_shape_must_be_whole_numbers(shape):
    from clholo.fft import FFTPlan

    with pytest.raises(InputError, match=r"shape=.* must be a sequence of ints \(whole numbers\)"):
        FFTPlan(shape)


def test_fft_plan_input_shape_must_be_whole_numbers():
    from clholo.fft import FFTPlan

    with pytest.raises(InputError, match=r"input_shape=\(4\.5, 4\) must be a tuple of 2 ints"):
        FFTPlan((8, 8), input_shape=(4.5, 4))
    assert FFTPlan((8.0, 8)).shape == (8, 8)  # a float with no fraction is a size


@pytest.mark.parametrize("value", [(16.7, 16), (True, 4), "ab", (3,)])
def test_shape2d_refuses_what_int_would_cut(value):
    from clholo import validate

    with pytest.raises(InputError, match=r"slm_shape must be a pair \(H, W\) of whole numbers"):
        validate.shape2d(value, name="slm_shape")
    assert validate.shape2d((16.0, np.int64(4)), name="slm_shape") == (16, 4)


# SGD

def test_sgd_on_a_device_array_at_an_offset_matches_numpy(queue):
    """``holograms[1:]`` of a device array starts at an offset: the kernels take buffers
    without one, so SGD ended in pyopencl's ArrayHasOffsetError."""
    import pyopencl.array as cla

    from clholo.encode import sgd_encode

    rng = np.random.default_rng(5)
    h = (rng.random((3, 1, 16, 16)) + 1j * rng.random((3, 1, 16, 16))).astype(np.complex64)
    optics = Optics(8e-6, (520e-9,))
    on_device = sgd_encode(cla.to_device(queue, h)[1:], optics, z_slm=0.01, iterations=3,
                           progress=False, queue=queue)
    on_host = sgd_encode(h[1:], optics, z_slm=0.01, iterations=3, progress=False, queue=queue)
    assert np.array_equal(on_device.phase, on_host.phase)


@pytest.mark.parametrize("roi, error, match", [
    ("all", InputTypeError, "roi must be an array"),
    (np.ones((16, 16), np.complex64), ValueError, "roi holds complex numbers"),
])
def test_sgd_roi_must_be_real_weights(queue, roi, error, match):
    from clholo.encode import sgd_encode

    h = np.ones((1, 1, 16, 16), np.complex64)
    with pytest.raises(error, match=match):
        sgd_encode(h, Optics(8e-6, (520e-9,)), z_slm=0.01, iterations=2, progress=False,
                   roi=roi, queue=queue)


def test_sgd_boolean_roi_is_a_mask(queue):
    from clholo.encode import sgd_encode

    rng = np.random.default_rng(1)
    h = (rng.random((1, 1, 16, 16)) + 1j).astype(np.complex64)
    mask = np.zeros((16, 16), bool)
    mask[4:12, 4:12] = True
    optics = Optics(8e-6, (520e-9,))
    as_bool = sgd_encode(h, optics, z_slm=0.01, iterations=3, progress=False, roi=mask,
                         queue=queue)
    as_float = sgd_encode(h, optics, z_slm=0.01, iterations=3, progress=False,
                          roi=mask.astype(np.float32), queue=queue)
    assert np.array_equal(as_bool.phase, as_float.phase)


def test_sgd_non_finite_init_says_so(queue):
    from clholo.encode import sgd_encode

    with pytest.raises(ValueError, match=r"init holds 256 NaN/inf value\(s\)"):
        sgd_encode(np.ones((1, 1, 16, 16), np.complex64), Optics(8e-6, (520e-9,)), z_slm=0.01,
                   iterations=2, progress=False, init=np.full((1, 1, 16, 16), np.nan),
                   queue=queue)


@pytest.mark.parametrize("exponent", [-100, -30, -21, 21, 63, 100])
@pytest.mark.parametrize("where", ["numpy", "device"])
def test_sgd_fits_a_target_of_any_amplitude(queue, exponent, where):
    """SGD's loss sums |field|^2 in float32: amplitudes of 1e19 gave NaN phases (a loss of
    1.0), 1e-25 nothing fitted (``clholo encode``: "mean loss 1", or "every fitted scale is
    zero"), with exit 0. The fit does not depend on the target's scale; the target far from
    unit amplitude is divided by a power of two first: the same patterns and loss bit for bit
    as the unscaled target's, the scale in the caller's units."""
    import pyopencl.array as cla

    from clholo.encode import sgd_encode

    rng = np.random.default_rng(2)
    h = (rng.random((2, 1, 16, 16)) + 1j * rng.random((2, 1, 16, 16))).astype(np.complex64)
    optics = Optics(8e-6, (520e-9,))
    plain = sgd_encode(h, optics, z_slm=0.01, iterations=8, progress=False, queue=queue)
    scaled = (h * np.float32(2.0 ** exponent)).astype(np.complex64)
    assert np.all(np.isfinite(scaled)) and np.all(scaled != 0)
    arg = scaled if where == "numpy" else cla.to_device(queue, scaled)
    r = sgd_encode(arg, optics, z_slm=0.01, iterations=8, progress=False, queue=queue)
    assert np.array_equal(r.phase, plain.phase) and np.array_equal(r.loss, plain.loss)
    np.testing.assert_array_equal(r.scale, plain.scale * np.float32(2.0 ** exponent))


def test_sgd_of_ordinary_amplitudes_is_not_rescaled():
    """Within 2^-20 .. 2^20 the target is taken as it is (no extra pass, the same bits)."""
    from clholo.encode.sgd import _amplitude_exponent

    h = np.full((1, 1, 4, 4), 3.0 + 4.0j, np.complex64)
    assert _amplitude_exponent(h * np.float32(2.0 ** 17), None) == 0  # 5 2^17 ~ 2^19.3
    assert _amplitude_exponent(h * np.float32(2.0 ** 21), None) == 23  # |3+4i| = 5 ~ 2^2.3
    assert _amplitude_exponent(h * np.float32(2.0 ** -25), None) == -23
    assert _amplitude_exponent(np.zeros((1, 1, 4, 4), np.complex64), None) == 0


@pytest.mark.parametrize("encode", ["sgd", "dpac"])
def test_subnormal_targets_are_refused(queue, encode):
    """A hologram stored at 1e-44 (every value a float32 subnormal, 3 bits left): DPAC gave
    "phase contains NaN/inf" (2^146 is beyond float32), SGD "every fitted scale is zero"."""
    from clholo.encode import dpac_encode, sgd_encode

    rng = np.random.default_rng(4)
    h = (np.exp(2j * np.pi * rng.random((1, 1, 16, 16))) * 1e-44).astype(np.complex64)
    optics = Optics(8e-6, (520e-9,))
    call = (lambda x: sgd_encode(x, optics, z_slm=0.01, iterations=2, progress=False,
                                 queue=queue)) if encode == "sgd" else \
        (lambda x: dpac_encode(x, optics, z_slm=0.01, queue=queue))
    with pytest.raises(InputError, match=r"^holograms reach an amplitude of only 1\.\d+e-44, "
                                         r"below float32's smallest normal number"):
        call(h)
    # the smallest normal amplitudes are fitted
    call((np.exp(2j * np.pi * rng.random((1, 1, 16, 16))) * 2e-38).astype(np.complex64))


# exception kinds and messages

def test_missing_fp64_is_the_machine_not_a_bug():
    from clholo.host import runtime

    class NoFp64:
        name = "toy"
        double_fp_config = 0
        extensions = ""

    with pytest.raises(EnvironmentProblem) as info:
        runtime.require_fp64(NoFp64(), "the test")
    assert info.value.exit_code == ExitCode.ENVIRONMENT and isinstance(info.value, TypeError)


def test_validators_raise_clholos_input_error():
    from clholo import validate

    for call in (lambda: validate.wavelength(532), lambda: validate.pitch(-1),
                 lambda: validate.depths([3e-3, 2e-3], sorted_=True),
                 lambda: validate.seed(-1), lambda: validate.count(0, name="frames")):
        with pytest.raises(InputError):
            call()


@pytest.mark.parametrize("distance", [1e300, -2e3])
def test_distances_beyond_a_bench_are_refused_not_overflowed(distance):
    """``propagate(f, 1e300, ...)`` ended in an OverflowError from the band limit."""
    from clholo import validate

    with pytest.raises(InputError, match=r"dz reaches .* m, beyond 1000 m"):
        validate.distance(distance)
    with pytest.raises(InputError, match="depths reaches"):
        MPI(np.ones((1, 4, 4, 1)), np.ones((1, 4, 4)), [abs(distance)])


def test_propagate_far_beyond_a_bench_is_named(queue):
    from clholo.propagation import propagate

    with pytest.raises(InputError, match="beyond 1000 m"):
        propagate(np.ones((8, 8), np.complex64), 1e300, wavelength=520e-9, pitch=8e-6,
                  queue=queue)


def test_boolean_depths_are_not_metres():
    with pytest.raises(InputTypeError, match="depths must be a real numeric array, got dtype "
                                             "bool"):
        MPI(np.ones((1, 4, 4, 1)), np.ones((1, 4, 4)), np.array([True]))


def test_placed_refuses_far_before_near_on_one_layer():
    m = MPI(np.ones((1, 4, 4, 1)), np.ones((1, 4, 4)), [2e-3])
    with pytest.raises(ValueError, match=r"far \(0\.001\) must be greater than near"):
        m.placed(5e-3, 1e-3)
    assert m.placed(5e-3, 5e-3).depths.tolist() == [5e-3]


def test_max_angle_of_a_channel_that_is_not_there():
    with pytest.raises(InputError, match="channel must be <= 2, got 5"):
        Optics().max_angle_rad(5)
    assert Optics().max_angle_rad(2) == pytest.approx(np.arcsin(450e-9 / 16e-6))


@pytest.mark.parametrize("call, error, match", [
    (lambda m: m.score(np.zeros((0, 8, 3)), np.zeros((0, 8, 3))), InputError,
     r"image is empty \(shape \(0, 8, 3\)\)"),
    (lambda m: m.scale_fit("ab", "cd"), InputTypeError, "image must be a real image array"),
    (lambda m: m.scale_fit(np.zeros(0), np.zeros(0)), InputError, "image is empty"),
    (lambda m: m.score(np.ones((8, 8)), np.ones((8, 8)), layout="xyz"), InputError,
     "layout must be 'auto', 'hwc' or 'chw', got 'xyz'"),
])
def test_metrics_name_what_they_cannot_score(call, error, match):
    from clholo import metrics

    with pytest.raises(error, match=match):
        call(metrics)


def test_warp_over_homographies_must_be_numbers():
    from clholo import rayoptics

    m = MPI(np.ones((2, 4, 4, 1)), np.ones((2, 4, 4)), [2e-3, 3e-3])
    with pytest.raises(InputTypeError, match="homographies must be 3x3 matrices"):
        rayoptics.warp_over(m, "identity")


def test_focal_stack_of_another_contexts_array_names_holograms(queue):
    import pyopencl as cl
    import pyopencl.array as cla

    from clholo.hologram import focal_stack

    other = cl.CommandQueue(cl.Context([queue.device]))
    h = cla.to_device(other, np.ones((1, 1, 8, 8), np.complex64))
    with pytest.raises(ValueError, match="holograms is a device array of another OpenCL "
                                         "context"):
        focal_stack(h, Optics(8e-6, (520e-9,)), [2e-3], queue=queue)


def test_gray_levels_out_of_range_name_the_values():
    from clholo.encode.quantize import PhaseLUT

    lut = PhaseLUT.linear()
    with pytest.raises(ValueError, match=r"got values -1\.\.3"):
        lut.to_phase(np.array([-1, 3]))
    with pytest.raises(ValueError, match="got dtype float64"):
        lut.to_phase(np.array([1.5]))


def test_pupil_lengths_in_millimetres_warn():
    from clholo import views
    from clholo.validate import DepthWarning

    with pytest.warns(DepthWarning, match="fourier_focal_length_m=100 m is more than 1 m"):
        views.pupil_geometry(Optics(), [[0.0, 0.0]], pupil_diameter_m=0.01,
                             fourier_focal_length_m=100)


def test_a_splat_wider_than_any_image_covers_it(queue):
    """A log-scale of 50 (5e21 scene units): the radius' cast to int64 overflowed (NumPy's
    "invalid value encountered in cast"), the splat was dropped, and the render said the scene
    "carries no light ... check the layers' alpha"."""
    import warnings

    from clholo.io import Camera, Gaussians
    from clholo.io.splats import project, rasterize_slabs, rasterize_slabs_reference, slab_edges

    cam = Camera(32, 24, 50.0, 50.0)
    s = float(np.exp(50.0))
    g = Gaussians([[0.1, -0.2, 5.0]], [[s, s, s]], [[1, 0, 0, 0]], [0.8], [[0.2, 0.5, 0.9]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        proj = project(g, cam)
    assert len(proj.depth) == 1
    slab, _ = slab_edges(proj.depth, 2)
    for alpha, _ in (rasterize_slabs_reference(proj, slab, 2, 32, 24),
                     rasterize_slabs(proj, slab, 2, 32, 24, queue=queue)):
        np.testing.assert_allclose(alpha[slab[0]], 0.8, rtol=1e-6)


# second round: the renderer and what sits around it

@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32, "f4"])
def test_transfer_function_of_a_real_dtype_is_refused(queue, dtype):
    """The kernel writes complex values: a real ``out`` of half the size was written past its
    end (a segfault, or glibc's "double free or corruption")."""
    from clholo.propagation import build_transfer_function

    with pytest.raises(InputTypeError, match="transfer functions are complex64 or complex128"):
        build_transfer_function(queue, (16, 16), 1e-3, wavelengths=[520e-9], pitch=8e-6,
                                dtype=dtype)


def test_transfer_function_arguments_are_named(queue):
    import pyopencl.array as cla

    from clholo.propagation import build_transfer_function

    args = dict(wavelengths=[520e-9], pitch=8e-6)
    with pytest.raises(InputError, match="padded must be at least 1 x 1"):
        build_transfer_function(queue, (0, 4), 1e-3, **args)
    with pytest.raises(InputError, match=r"padded must be a pair \(H, W\) of whole numbers"):
        build_transfer_function(queue, (4.5, 4), 1e-3, **args)
    with pytest.raises(ValueError, match="C-contiguous complex64 device array"):
        build_transfer_function(queue, (16, 16), 1e-3, out=cla.empty(
            queue, (1, 16, 16), np.float32), **args)
    with pytest.raises(InputTypeError, match="out must be a pyopencl device array"):
        build_transfer_function(queue, (16, 16), 1e-3, out=np.empty((1, 16, 16), np.complex64),
                                **args)
    one = build_transfer_function(queue, (16, 16), 1e-3, wavelengths=520e-9, pitch=8e-6).get()
    listed = build_transfer_function(queue, (16, 16), 1e-3, **args).get()
    assert np.array_equal(one, listed)  # a single wavelength may be a number


def _primitives(conic=(0.5, 0.1, 0.4)):
    from clholo.baselines.rpws import Primitives

    return Primitives(np.array([[8.0, 6.0], [4.0, 3.0]]), np.array([conic, (0.3, 0.0, 0.3)]),
                      np.array([0.8, 0.6]), np.array([[0.5], [0.7]]), np.array([2e-3, 3e-3]),
                      np.array([6.0, 6.0]), (12, 16))


@pytest.mark.parametrize("alpha_max, alpha_min", [(0.0, 1 / 255), (0.99, 0.999), (0.99, -1.0),
                                                  (2.0, 1 / 255), (float("nan"), 1 / 255)])
def test_rpws_alpha_cut_outside_its_range_is_refused(queue, alpha_max, alpha_min):
    """alpha_max=0 or alpha_min=0.999 rendered a hologram of zeros, alpha_min=-1 one 5 %
    off, without a word."""
    from clholo.baselines.rpws import render_rpws

    with pytest.raises(ValueError, match="alpha"):
        render_rpws(_primitives(), Optics(8e-6, (520e-9,)), frames=1, alpha_max=alpha_max,
                    alpha_min=alpha_min, queue=queue)
    with pytest.raises(ValueError, match="alpha"):
        _primitives().footprints(alpha_max=alpha_max, alpha_min=alpha_min)


@pytest.mark.parametrize("conic", [(-0.5, 0.0, -0.5), (0.2, 1.0, 0.2), (0.0, 0.0, 1.0)])
def test_rpws_conic_must_be_positive_definite(conic):
    """A conic that is not positive definite made every footprint fill its box at the clamp:
    a hologram 196 % off, without an error."""
    with pytest.raises(ValueError, match=r"conic of primitive 0 is .* must be positive definite"):
        _primitives(conic)


@pytest.mark.parametrize("start", [2.7, "1", True, -1])
def test_frame_starts_are_whole_numbers(queue, start):
    """``iter_frames(start=2.7)`` rendered frames 2.. (int() cut it): another frame's phases."""
    from clholo.hologram import HologramRenderer

    m = MPI(np.ones((1, 8, 8, 1)) * 0.5, np.ones((1, 8, 8)), [2e-3])
    r = HologramRenderer(m, Optics(8e-6, (520e-9,)), queue=queue)
    with pytest.raises((InputError, InputTypeError), match="start"):
        list(r.iter_frames(2, start=start))


def test_frame0_is_a_whole_number(queue):
    import pyopencl.array as cla

    from clholo.hologram import HologramRenderer

    m = MPI(np.ones((1, 8, 8, 1)) * 0.5, np.ones((1, 8, 8)), [2e-3])
    r = HologramRenderer(m, Optics(8e-6, (520e-9,)), queue=queue)
    out = cla.empty(queue, (2, 1, 8, 8), np.complex64)
    with pytest.raises(InputTypeError, match="frame0"):
        r.enqueue_frames(1.9, 2, out)


@pytest.mark.parametrize("option", ["fuse_composite", "two_pass"])
def test_renderer_switches_must_be_bools(queue, option):
    from clholo.hologram import HologramRenderer

    m = MPI(np.ones((1, 8, 8, 1)) * 0.5, np.ones((1, 8, 8)), [2e-3])
    with pytest.raises(InputTypeError, match=f"{option} must be True or False, got 'no'"):
        HologramRenderer(m, Optics(8e-6, (520e-9,)), queue=queue, **{option: "no"})


def test_a_focal_length_without_a_pupil_diameter_is_refused():
    from clholo import views

    with pytest.raises(ValueError, match="fourier_focal_length_m sizes a pupil given by "
                                         "pupil_diameter_m"):
        views.pupil_geometry(Optics(), [[0.0, 0.0]], fourier_focal_length_m=0.1)


def _rgbd_files(tmp_path, depth):
    from clholo.io import write_image

    rng = np.random.default_rng(4)
    write_image(tmp_path / "img.png", rng.random((16, 16, 3)), dtype="uint8")
    np.save(tmp_path / "depth.npy", depth)
    return tmp_path / "img.png", tmp_path / "depth.npy"


@pytest.mark.parametrize("option, value", [("width", 100), ("height", 80), ("fov_deg", 40.0),
                                           ("backend", "numpy")])
def test_splat_options_on_an_rgbd_scene_are_refused(tmp_path, option, value):
    """``load_scene((img, depth), width=100)`` ignored width: an option acts or is refused."""
    from clholo.io import load_scene

    img, depth = _rgbd_files(tmp_path, np.random.default_rng(0).random((16, 16)) + 1)
    with pytest.raises(ValueError, match=f"{option} apply to 3D Gaussian splat .ply inputs"):
        load_scene((img, depth), near=2e-3, far=6e-3, **{option: value})


def test_a_depth_map_given_first_says_they_look_swapped(tmp_path):
    from clholo.io import load_scene

    img, depth = _rgbd_files(tmp_path, np.random.default_rng(0).random((16, 16)) + 1)
    with pytest.raises(InputError, match=r"depth\.npy is a depth map's format \(\.npy\), given "
                                         r"where the colour image goes; they look swapped"):
        load_scene((depth, img), near=2e-3, far=6e-3)


def test_a_mostly_invalid_depth_map_is_filled_with_a_warning(tmp_path):
    from clholo.io import DepthMapWarning, load_scene

    d = np.random.default_rng(0).random((16, 16)) + 1
    d[:, :10] = np.nan  # 62 % invalid
    img, depth = _rgbd_files(tmp_path, d)
    with pytest.warns(DepthMapWarning, match="62% of its pixels are invalid"):
        load_scene((img, depth), near=2e-3, far=6e-3)
    d[:, 5:10] = 1.5  # 31 %: a sensor's holes, filled without a word
    np.save(depth, d)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", DepthMapWarning)
        load_scene((img, depth), near=2e-3, far=6e-3)


def _rgbz_exr(path, z):
    from clholo.io import write_image

    rng = np.random.default_rng(5)
    px = np.concatenate([rng.random((16, 16, 3)), z[..., None]], -1).astype(np.float32)
    write_image(path, px, channel_names=("R", "G", "B", "Z"))
    return path


def test_an_exr_with_its_own_depth_and_a_second_map_warns(tmp_path):
    from clholo.io import DepthMapWarning, load_scene

    exr = _rgbz_exr(tmp_path / "rgbz.exr", np.linspace(1, 2, 256).reshape(16, 16))
    np.save(tmp_path / "depth.npy", np.full((16, 16), 1.5))
    with pytest.warns(DepthMapWarning, match=r"carries its own depth channel \(Z\)"):
        load_scene((exr, tmp_path / "depth.npy"), near=2e-3, far=6e-3)


def test_an_exrs_depth_channel_is_not_disparity(tmp_path):
    from clholo.io import load_scene

    exr = _rgbz_exr(tmp_path / "rgbz.exr", np.linspace(1, 2, 256).reshape(16, 16))
    with pytest.raises(InputError, match="would turn the scene inside out"):
        load_scene(exr, near=2e-3, far=6e-3, depth_kind="disparity")
    assert load_scene(exr, near=2e-3, far=6e-3).layers == 32


# third round: encode, images, patterns

@pytest.mark.parametrize("codes, dtype", [(np.uint8, "uint16"), (np.uint16, "uint8"),
                                          (np.int64, "uint8")])
def test_write_image_refuses_codes_of_another_width(tmp_path, codes, dtype):
    """They were clipped to [0, 1] and scaled: every code >= 1 stored as full white."""
    from clholo.io import write_image

    with pytest.raises(InputError, match=rf"pixels are {np.dtype(codes).name} codes but "
                                         rf"dtype='{dtype}' stores"):
        write_image(tmp_path / "x.png", np.arange(12, dtype=codes).reshape(3, 4), dtype=dtype)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("pixels, dtype, match", [
    (np.full((2, 2), np.nan), "uint8", "pixels hold NaN"),
    (np.full((2, 2), 1e5), "half", "beyond dtype='half'"),
    (np.full((2, 2), 1e39), "float", "beyond dtype='float'"),
    (np.ones((2, 2), np.complex64), "float", "pixels must be real numbers"),
    (np.ones(4), "float", r"pixels must have shape \(H, W\) or \(H, W, C\)"),
])
def test_write_image_refuses_what_it_would_store_as_something_else(tmp_path, pixels, dtype,
                                                                    match):
    from clholo.io import write_image

    with pytest.raises((InputError, InputTypeError), match=match):
        write_image(tmp_path / "x.exr", pixels, dtype=dtype)
    with pytest.raises(InputError, match="channel_names has 2 name"):
        write_image(tmp_path / "y.exr", np.ones((2, 2, 3)), channel_names=("R", "G"))


def test_write_image_still_writes_what_it_should(tmp_path):
    from clholo.io import read_image, write_image

    codes = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    write_image(tmp_path / "a.png", codes, dtype="uint16")
    assert np.array_equal(read_image(tmp_path / "a.png", normalise=False)[0][..., 0], codes)
    write_image(tmp_path / "b.png", np.array([[0.0, 0.5, 1.0]]), dtype="uint8")
    assert read_image(tmp_path / "b.png", normalise=False)[0][..., 0].tolist() == [[0, 128, 255]]


@pytest.mark.parametrize("exponent", [-100, -70, 70, 100])
def test_dpac_of_any_amplitude_gives_the_same_patterns(queue, exponent):
    """The largest |u| came from |u|^2 in float32: 1e20 gave phases 1.42 rad off (flat
    checkerboards), 3e38 all NaN, without an error."""
    from clholo.encode import dpac_encode

    rng = np.random.default_rng(6)
    h = (rng.random((1, 2, 16, 16)) + 1j * rng.random((1, 2, 16, 16))).astype(np.complex64)
    optics = Optics(8e-6, (638e-9, 520e-9))
    plain = dpac_encode(h, optics, z_slm=0.01, queue=queue)
    scaled = dpac_encode((h * np.float32(2.0 ** exponent)).astype(np.complex64), optics,
                         z_slm=0.01, queue=queue)
    assert np.array_equal(scaled, plain)
    big = dpac_encode((h / np.abs(h).max() * np.float32(3e38)).astype(np.complex64), optics,
                      z_slm=0.01, queue=queue)
    assert np.all(np.isfinite(big)) and np.abs(big - plain).max() < 1e-5


def test_dpac_amax_beyond_float32_is_refused(queue):
    from clholo.encode import dpac_encode

    with pytest.raises(ValueError, match="amax must be a positive amplitude within float32"):
        dpac_encode(np.ones((1, 1, 8, 8), np.complex64), Optics(8e-6, (520e-9,)), z_slm=0.01,
                    amax=1e39, queue=queue)


def test_focal_stack_of_amplitudes_whose_intensities_overflow_is_refused(queue):
    from clholo.hologram import focal_stack

    with pytest.raises(ValueError, match=r"amplitude of 1e\+19, beyond 1e\+15"):
        focal_stack(np.full((1, 1, 8, 8), 1e19, np.complex64), Optics(8e-6, (520e-9,)),
                    [2e-3], queue=queue)


def test_scale_fit_of_large_float32_images_is_finite():
    from clholo import metrics

    ref = np.random.default_rng(0).random((8, 8)).astype(np.float32)
    assert metrics.scale_fit(ref * np.float32(3e38), ref) == pytest.approx(1 / 3e38, rel=1e-6)


def test_pattern_folder_with_16_bit_levels_is_refused(tmp_path):
    """16-bit PNGs were read into uint8: 1000 became 232 (modulo 256)."""
    from clholo.encode.quantize import read_pattern_pngs, write_pattern_pngs
    from clholo.io import write_image

    folder = write_pattern_pngs(np.zeros((1, 1, 8, 8), np.uint8), tmp_path / "p")
    png = next(folder.glob("*.png"))
    png.unlink()
    write_image(png, np.full((8, 8), 1000, np.uint16), dtype="uint16")
    with pytest.raises(ValueError, match="holds uint16 levels, not the SLM's 8-bit gray levels"):
        read_pattern_pngs(folder)


def test_pattern_json_of_an_impossible_size_is_refused_before_allocating(tmp_path):
    import json

    from clholo.encode.quantize import read_pattern_pngs, write_pattern_pngs

    folder = write_pattern_pngs(np.zeros((1, 1, 8, 8), np.uint8), tmp_path / "p")
    info = json.loads((folder / "patterns.json").read_text())
    info["rows"] = 10 ** 7
    (folder / "patterns.json").write_text(json.dumps(info))
    with pytest.raises(InputError, match="rows = 10000000 is larger than any SLM"):
        read_pattern_pngs(folder)
    info.update(rows=8, channels=["R", "R"])
    (folder / "patterns.json").write_text(json.dumps(info))
    with pytest.raises(InputError, match="names a colour twice"):
        read_pattern_pngs(folder)


@pytest.mark.parametrize("convert", ["srgb_to_linear", "linear_to_srgb"])
def test_srgb_conversions_refuse_codes_and_non_numbers(convert):
    """uint8 codes were taken as values of [0, 1]: 255 decoded to 524946."""
    from clholo import io as cio

    f = getattr(cio, convert)
    with pytest.raises(InputTypeError, match="codes of 0..255\\? divide by 255 first"):
        f(np.array([0, 128, 255], np.uint8))
    for bad in ("0.5", np.array([1 + 1j])):
        with pytest.raises(InputTypeError, match="v must be"):
            f(bad)
    assert f(1) == pytest.approx(1.0)
    np.testing.assert_allclose(f(np.array([0, 1])), [0.0, 1.0], atol=1e-15)


# operators whose host result would hold NaN/inf: a device array is not scanned before the
# work, and huge amplitudes overflow float32 intensities; the result is checked instead

def _views_input(queue, *, bad):
    import pyopencl.array as cla

    rng = np.random.default_rng(7)
    h = (rng.standard_normal((2, 1, 32, 32))
         + 1j * rng.standard_normal((2, 1, 32, 32))).astype(np.complex64)
    if bad == "nan":
        h[1, 0, 5, 9] = np.nan
        return cla.to_device(queue, h)
    if bad == "inf":
        h[0, 0, 30, 2] = np.inf
        return cla.to_device(queue, h)
    return h * np.float32(1e25)  # NumPy, finite: intensities beyond float32


@pytest.mark.parametrize("operator", ["focal_stack", "pupil_view", "light_field"])
@pytest.mark.parametrize("bad", ["nan", "inf", "huge"])
def test_operators_refuse_results_holding_nan(queue, operator, bad):
    from clholo import views
    from clholo.hologram import focal_stack

    optics = Optics(pitch=8e-6, wavelengths=(520e-9,))
    h = _views_input(queue, bad=bad)
    call = {"focal_stack": lambda: focal_stack(h, optics, [1e-3], queue=queue),
            "pupil_view": lambda: views.pupil_view(h, optics, focus_depth=1e-3,
                                                   angles_rad=[(0.0, 0.0)], queue=queue),
            "light_field": lambda: views.light_field(h, optics, window=8, queue=queue)}[operator]
    what = {"focal_stack": "focal stack", "pupil_view": "pupil views",
            "light_field": "light field"}[operator]
    if operator == "focal_stack" and bad == "huge":  # refused before the work, by amplitude
        with pytest.raises(ValueError, match=r"holograms reach an amplitude of \d\.\d+e\+25"):
            call()
        return
    cause = (r"a device array, not scanned before the work\) hold NaN/inf" if bad != "huge"
             else r"amplitudes are so large that their intensities overflow float32")
    with pytest.raises(ValueError, match=rf"^\d+ value\(s\) of the {what} are NaN or inf: "
                                         rf".*{cause}"):
        call()
    if bad != "huge":  # the same device holograms without the bad value: a finite result
        import pyopencl.array as cla

        fine = h.get()
        fine[~np.isfinite(fine)] = 0
        h = cla.to_device(queue, fine)
        result = call()
        result = result.intensity if operator == "light_field" else result
        assert np.all(np.isfinite(result)) and result.max() > 0
