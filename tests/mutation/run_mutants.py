"""Mutation campaign of issue 18 section 3: do the tests pin the physics?

Each mutant is one small, plausible physics mistake put into the newer kernel families and
their host code, either alone (``ordinary``) or, for ``both``, the same wrong physics put into a
kernel (or its host code) AND its NumPy reference in ``clholo/reference/`` together, so that a
test of the kernel against its reference cannot see it: only a test against physics can.

For every mutant the script edits the files in place (each ``find`` text must occur exactly
once), runs the mutant's pytest selection (the family's test files plus
``tests/test_physics_pins.py``) with ``-x -q -p no:cacheprovider`` under a timeout, classifies
the result and restores every edited file with ``git checkout -- FILE`` (also on Ctrl-C,
SIGTERM and timeouts):

* ``caught``: a test failed (the first failing test is recorded);
* ``missed``: every selected test passed;
* ``broken``: the mutant does not build (a kernel build error or a Python syntax error): not
  counted, replace it with another mutant;
* ``timeout``: the selection ran past the timeout (counted as caught, and flagged).

It refuses to start when a file it would edit has uncommitted changes (``git checkout`` would
throw them away), and waits while ``/tmp/clholo-bench.lock`` exists (another engineer taking
timings) before each run.

Usage (from the repository root)::

    .venv/bin/python tests/mutation/run_mutants.py                 # every mutant
    .venv/bin/python tests/mutation/run_mutants.py --only E01,S02  # some
    .venv/bin/python tests/mutation/run_mutants.py --check         # find texts only, no runs
    .venv/bin/python tests/mutation/run_mutants.py --list

Results go to ``tests/mutation/results.csv`` and ``tests/mutation/results.md`` (``--out``
changes the stem). Not collected by pytest (its name does not start with ``test_``).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

ROOT = Path(__file__).resolve().parents[2]
LOCK = Path("/tmp/clholo-bench.lock")
PINS = "tests/test_physics_pins.py"

# the pytest selection of each family (the pins are added to every one)
FAMILY_TESTS = {
    "views": ["tests/test_views.py"],
    "rayoptics": ["tests/test_rayoptics.py"],
    "encode": ["tests/test_encode.py"],
    "rpws": ["tests/test_rpws.py"],
    "splats": ["tests/test_splats.py"],
    "composite": ["tests/test_composite.py", "tests/test_hologram.py",
                  "tests/test_mpi_physics.py", "tests/test_hologram_fused.py"],
    "asm": ["tests/test_propagation.py", "tests/test_reference_physics.py",
            "tests/test_mpi_physics.py"],
    "metrics": ["tests/test_metrics.py", "tests/test_scores_per_colour.py"],
    "rgbd": ["tests/test_baselines_rgbd.py", "tests/test_io_rgbd.py"],
}

# NumPy references outside clholo/reference/: the splat rasteriser's lives beside its host code
REFERENCES = {"clholo/io/splats.py"}

Edit = Tuple[str, str, str]  # (file, exact text to find, replacement)


@dataclass
class Mutant:
    id: str
    family: str
    kind: str  # "ordinary" or "both"
    change: str  # the mistake, in words
    edits: List[Edit]
    tests: Optional[List[str]] = None  # default: the family's files

    def selection(self) -> List[str]:
        return list(self.tests or FAMILY_TESTS[self.family]) + [PINS]


KV, RV, VP, HV = ("kernels/views.cl", "clholo/reference/views.py", "clholo/views.py",
                  "host/views.py")
KR, RR, RO = "kernels/rayoptics.cl", "clholo/reference/rayoptics.py", "clholo/rayoptics.py"
KE, RE, PR = "kernels/encode.cl", "clholo/reference/encode.py", "host/phase_retrieval.py"
KSG, KSC = "kernels/sgd_step.h", "kernels/sgd_callbacks.h"
KP, RP, BP, HP = ("kernels/rpws.cl", "clholo/reference/rpws.py", "clholo/baselines/rpws.py",
                  "host/rpws.py")
KS, SP = "kernels/splat_raster.cl", "clholo/io/splats.py"
KC, KCS, SCH, R0 = ("kernels/composite.cl", "kernels/composite_store.h", "host/scheduler.py",
                    "clholo/reference/core.py")
KCB = "kernels/composite_cpu.cl"  # layer_blocks: the CPU renderer's amp and keep
PROP = "clholo/propagation.py"
KA = "kernels/asm.cl"
MET = "clholo/metrics.py"
RB = "clholo/reference/baselines.py"

MUTANTS: List[Mutant] = [
    # ------------------------------------------------------------------ views (pupil, STFT)
    Mutant("V01", "views", "both", "Hann taper 0.5 + 0.5 cos (peaked at the window's edges)", [
        (KV, "t = (0.5f - 0.5f * cos(k * (float)i)) * (0.5f - 0.5f * cos(k * (float)j));",
         "t = (0.5f + 0.5f * cos(k * (float)i)) * (0.5f + 0.5f * cos(k * (float)j));"),
        (RV, "return 0.5 - 0.5 * np.cos(2 * np.pi * i / window)",
         "return 0.5 + 0.5 * np.cos(2 * np.pi * i / window)")]),
    Mutant("V02", "views", "both", "STFT bin angle atan instead of asin of lambda k / (w p)", [
        (VP, "angles = np.arcsin(lams[:, None] * k[None, :] / (w * optics.pitch))",
         "angles = np.arctan(lams[:, None] * k[None, :] / (w * optics.pitch))"),
        (RV, "return np.arcsin(np.clip(wavelength * k / (window * pitch), -1.0, 1.0))",
         "return np.arctan(wavelength * k / (window * pitch))")]),
    Mutant("V03", "views", "both",
           "pupil centre at -sin(theta)/lambda (viewing direction flipped)", [
        (VP, "centres = sines[:, None, :] / lams[None, :, None]",
         "centres = -sines[:, None, :] / lams[None, :, None]"),
        (RV, "centre=(math.sin(tx) / lam, math.sin(ty) / lam)",
         "centre=(-math.sin(tx) / lam, -math.sin(ty) / lam)")]),
    Mutant("V04", "views", "both", "pupil view refocuses by +d instead of -d", [
        (VP, "queue, padded, -d, wavelengths=optics.wavelengths, pitch=p,",
         "queue, padded, d, wavelengths=optics.wavelengths, pitch=p,"),
        (RV, "reference.transfer_function(padded, -focus_depth,",
         "reference.transfer_function(padded, focus_depth,")]),
    Mutant("V05", "views", "ordinary", "pupil radius in bins: x and y grid sizes swapped", [
        (VP, "pupils[..., 2] = (radii * Wp * p)[None]", "pupils[..., 2] = (radii * Hp * p)[None]"),
        (VP, "pupils[..., 3] = (radii * Hp * p)[None]",
         "pupils[..., 3] = (radii * Wp * p)[None]")]),
    Mutant("V06", "views", "ordinary", "STFT window stored transposed (x and y swapped)", [
        (KV, "out[((size_t)b * get_global_size(1) + n) * (size_t)(w * w) + ij] = t * v;",
         "out[((size_t)b * get_global_size(1) + n) * (size_t)(w * w) + j * w + i] = t * v;")]),
    Mutant("V07", "views", "ordinary", "light field chunk weight 1/chunk instead of 1/T", [
        (HV, "np.float32(1.0 / T), np.uint32(w), np.uint32(n))",
         "np.float32(1.0 / n), np.uint32(w), np.uint32(n))")]),
    Mutant("V08", "views", "ordinary", "SLM angle limit lambda/p instead of lambda/(2p)", [
        (VP, "limits = lams / (2 * optics.pitch)", "limits = lams / optics.pitch")]),
    Mutant("V09", "views", "ordinary", "light field fftshift off by one bin", [
        (KV, "const uint h = (w + 1u) / 2u;", "const uint h = (w + 1u) / 2u - 1u;")]),
    Mutant("V10", "views", "both", "light field frame sum not divided by T", [
        (HV, "np.float32(1.0 / T), np.uint32(w), np.uint32(n))",
         "np.float32(1.0), np.uint32(w), np.uint32(n))"),
        (RV, "return np.fft.fftshift(p.mean(axis=0), axes=(-2, -1))",
         "return np.fft.fftshift(p.sum(axis=0), axes=(-2, -1))")]),
    # ------------------------------------------------------------------ ray optics
    Mutant("R01", "rayoptics", "both", "premultiplied interpolation forgets alpha in c*a", [
        (KR, "const float wc = wt * at;", "const float wc = wt;"),
        (RR, "ca = bilinear_sample(color[layer, ..., c] * alpha[layer], sx, sy)",
         "ca = bilinear_sample(color[layer, ..., c], sx, sy)")]),
    Mutant("R02", "rayoptics", "both", "layers composited in the wrong order (farthest on top)", [
        (KR, "for (int l = 0; l < L && trans > 0.0f; ++l) {",
         "for (int l = L - 1; l >= 0 && trans > 0.0f; --l) {"),
        (RR, "for layer in range(L - 1, -1, -1):  # back to front",
         "for layer in range(L):  # back to front")]),
    Mutant("R03", "rayoptics", "both", "bilinear weights swapped (1 - t for t)", [
        (KR, "const float wt = ((j & 1) ? tx : 1.0f - tx) * ((j >> 1) ? ty : 1.0f - ty);",
         "const float wt = ((j & 1) ? 1.0f - tx : tx) * ((j >> 1) ? 1.0f - ty : ty);"),
        (RR, "wt = (tx if dx else 1 - tx) * (ty if dy else 1 - ty)",
         "wt = (1 - tx if dx else tx) * (1 - ty if dy else ty)")]),
    Mutant("R04", "rayoptics", "both", "transmission alpha instead of 1 - alpha", [
        (KR, "trans *= 1.0f - a;", "trans *= a;"),
        (RR, "acc = acc * (1 - a) + ca", "acc = acc * a + ca")]),
    Mutant("R05", "rayoptics", "ordinary", "layer shift (f - d) tan(theta) (sign of the shift)", [
        (RO, "return (depths[None, :, None] - focus_depth) * slopes[:, None, :] / pitch",
         "return (focus_depth - depths[None, :, None]) * slopes[:, None, :] / pitch")]),
    Mutant("R06", "rayoptics", "ordinary", "pupil directions: cell edges instead of midpoints", [
        (RO, "u = (2 * np.arange(n) + 1 - n) / n", "u = (2 * np.arange(n) - n) / n")]),
    Mutant("R07", "rayoptics", "ordinary", "perspective magnification inverted d/(d - tz)", [
        (RO, "k = (d - tz) / d", "k = d / (d - tz)")]),
    Mutant("R08", "rayoptics", "ordinary",
           "default focal-slice pupil half-angle asin(lambda/2p)/2 (diameter for radius)", [
        (RO, "halves = [optics.max_angle_rad(c) for c in range(C)]",
         "halves = [optics.max_angle_rad(c) / 2 for c in range(C)]")]),
    Mutant("R09", "rayoptics", "ordinary", "perspective y shift about cx instead of cy", [
        (RO, "hom[:, 1, 2] = cy - cy * k + fy * ty / d",
         "hom[:, 1, 2] = cx - cx * k + fy * ty / d")]),
    # ------------------------------------------------------------------ encode (SGD, DPAC)
    Mutant("E01", "encode", "both", "Adam: first-moment bias correction dropped", [
        (KSG, "const TY p = (p_old) - lr * (m / bc1) / (sqrt(v / bc2) + eps);",
         "const TY p = (p_old) - lr * m / (sqrt(v / bc2) + eps);"),
        (RE, "phase = phase - lr * (m / bc1) / (np.sqrt(v / bc2) + eps)",
         "phase = phase - lr * m / (np.sqrt(v / bc2) + eps)")]),
    Mutant("E02", "encode", "both", "phase gradient without its factor 2", [
        (KSG, "#define SGD_PHASE_GRADIENT(gr, gi, xr, xi) (2 * ((gi) * (xr) - (gr) * (xi)))",
         "#define SGD_PHASE_GRADIENT(gr, gi, xr, xi) (((gi) * (xr) - (gr) * (xi)))"),
        (RE, "grad = 2.0 * np.imag(g * np.conj(x))", "grad = np.imag(g * np.conj(x))")]),
    Mutant("E03", "encode", "both", "adjoint propagates by +z instead of -z", [
        (PR, "cache.get(q, padded, -z,", "cache.get(q, padded, z,"),
        (RE, "transfer_function(padded, -z,", "transfer_function(padded, z,")]),
    Mutant("E04", "encode", "both", "<y, t> conjugates t instead of y", [
        (KE, "const REAL2 c = cmul(cconj(yv), tv);", "const REAL2 c = cmul(yv, cconj(tv));"),
        (KE, "im += (w) * ((yr) * (ti) - (yi) * (tr));",
         "im += (w) * ((yi) * (tr) - (yr) * (ti));"),
        (RE, "c = np.sum(m2 * np.conj(y) * t, axis=(-2, -1))",
         "c = np.sum(m2 * y * np.conj(t), axis=(-2, -1))")]),
    Mutant("E05", "encode", "both", "DPAC offset asin(a) instead of acos(a)", [
        (KE, "const REAL d = acos(a);", "const REAL d = asin(a);"),
        (RE, "d = np.arccos(a)", "d = np.arcsin(a)")]),
    Mutant("E06", "encode", "both", "DPAC amplitude from |u|^2 (sqrt dropped)", [
        (KE, "fmin(sqrt(cabs2(uv)) / am, (REAL)1)", "fmin(cabs2(uv) / am, (REAL)1)"),
        (RE, "np.minimum(np.abs(u) / amax, 1.0)", "np.minimum(np.abs(u) ** 2 / amax, 1.0)")]),
    Mutant("E07", "encode", "both", "SGD loss 1 - |<y,t>|/(|y||t|) (amplitude, not squared)", [
        (KE, "fmax((REAL)0, 1 - cabs2(c) / (yy * tt))",
         "fmax((REAL)0, 1 - sqrt(cabs2(c) / (yy * tt)))"),
        (RE, "loss = 1.0 - np.abs(c) ** 2 / (yy * tt)",
         "loss = 1.0 - np.abs(c) / np.sqrt(yy * tt)")]),
    Mutant("E08", "encode", "both", "Adam second moment of |g| instead of g^2", [
        (KSG, "const TY v = b2 * (v_old) + one_minus_b2 * (d) * (d);",
         "const TY v = b2 * (v_old) + one_minus_b2 * fabs(d);"),
        (RE, "v = beta2 * v + (1 - beta2) * grad * grad",
         "v = beta2 * v + (1 - beta2) * np.abs(grad)")]),
    Mutant("E09", "encode", "both", "gradient normalised by ||y||^2 instead of ||t||^2", [
        (KE, "weight[b] = tt > 0 ? 1 / tt : (REAL)0;", "weight[b] = yy > 0 ? 1 / yy : (REAL)0;"),
        (RE, "(np.conj(s) / tt)[:, None, None]", "(np.conj(s) / yy)[:, None, None]")]),
    Mutant("E10", "encode", "ordinary", "init='target' propagates the target forward, not back", [
        ("clholo/encode/sgd.py",
         "back = engine.propagator.apply(target, engine.tf_adjoint, tf_even=True)",
         "back = engine.propagator.apply(target, engine.tf_forward, tf_even=True)")]),
    Mutant("E11", "encode", "ordinary", "field_max_abs returns max |u|^2 (sqrt dropped)", [
        (KE, "out[b] = sqrt(scratch[0]);", "out[b] = scratch[0];")]),
    Mutant("E12", "encode", "ordinary", "Adam bias corrections one step ahead (b^(t+1))", [
        (PR, "return [self.lr, b1, b2, 1.0 - b1, 1.0 - b2, self.eps, 1.0 - b1 ** t, 1.0 - b2 ** t]",
         "return [self.lr, b1, b2, 1.0 - b1, 1.0 - b2, self.eps, 1.0 - b1 ** (t + 1), "
         "1.0 - b2 ** (t + 1)]")]),
    Mutant("E13", "encode", "ordinary", "SLM simulation propagates by -z_slm", [
        ("clholo/encode/simulate.py",
         "queue, padded, z_slm, wavelengths=optics.wavelengths, pitch=optics.pitch)",
         "queue, padded, -z_slm, wavelengths=optics.wavelengths, pitch=optics.pitch)")]),
    Mutant("E15", "encode", "ordinary",
           "fused residual (one pixel at a time) reads the ROI mask transposed", [
        (KSC, "const real m = has_mask ? mask[p] : (real)1;",
         "const real m = has_mask ? mask[(size_t)col * height + (uint)row] : (real)1;")]),
    Mutant("E16", "encode", "ordinary",
           "fused Adam store (eight pixels) writes the second moment as the first", [
        (KSC, "vstore8(m, 0, adam_m + k);", "vstore8(v, 0, adam_m + k);")]),
    Mutant("E17", "encode", "ordinary",
           "four-pass iteration adds A^H(m t) to the gradient field instead of subtracting", [
        (KSC, "const TY gr = (a) * (ur) - ((swx) * (tr) + (swy) * (ti));",
         "const TY gr = (a) * (ur) + ((swx) * (tr) + (swy) * (ti));"),
        (KSC, "const TY gi = (a) * (ui) - ((swx) * (ti) - (swy) * (tr));",
         "const TY gi = (a) * (ui) + ((swx) * (ti) - (swy) * (tr));")]),
    Mutant("E18", "encode", "ordinary",
           "four-pass iteration's forward mid passes y on without the ROI weights", [
        (KSC, "    return has_mask ? roi * y : y;", "    return y;"),
        (KSC, "            re[l] = w * yr;\n            im[l] = w * yi;",
         "            re[l] = yr;\n            im[l] = yi;")]),
    Mutant("E19", "encode", "ordinary",
           "four-pass loss sums on the CPU strips (eight rows) add Im(y conj(t))", [
        (KSC, "acc[1] += w * (yr * ti - yi * tr);", "acc[1] += w * (yi * tr - yr * ti);")]),
    Mutant("E14", "encode", "ordinary",
           "residual multiplied by s instead of conj(s) (kernels and callbacks)", [
        (KSG, "const TY out_r = (mw) * ((sx) * out_r##_r - (-(sy)) * out_r##_i);",
         "const TY out_r = (mw) * ((sx) * out_r##_r - (sy) * out_r##_i);"),
        (KSG, "const TY out_i = (mw) * ((sx) * out_r##_i + (-(sy)) * out_r##_r);",
         "const TY out_i = (mw) * ((sx) * out_r##_i + (sy) * out_r##_r);")]),
    # ------------------------------------------------------------------ RPWS
    Mutant("P01", "rpws", "both",
           "footprint cross term b dx dy halved (-1/2 (a dx^2 + b dxdy + c dy^2))", [
        (KP, "const float power = -0.5f * (g.s2 * dx * dx + g.s4 * dy * dy) - g.s3 * dx * dy;",
         "const float power = -0.5f * (g.s2 * dx * dx + g.s4 * dy * dy + g.s3 * dx * dy);"),
        (RP, "power = f32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy",
         "power = f32(-0.5) * (a * dx * dx + c * dy * dy + b * dx * dy)")]),
    Mutant("P02", "rpws", "both", "alpha clamp 0.99 applied before the opacity", [
        (KP, "const float alpha = fmin(alpha_max, g.s5 * exp(power));",
         "const float alpha = g.s5 * fmin(alpha_max, exp(power));"),
        (RP, "alpha = np.minimum(f32(alpha_max), f32(opacity) * np.exp(power.astype(f32)))",
         "alpha = f32(opacity) * np.minimum(f32(alpha_max), np.exp(power.astype(f32)))")]),
    Mutant("P03", "rpws", "both", "pixel centres at (x + 0.5, y + 0.5)", [
        (KP, "const float dx = g.s0 - (float)x;", "const float dx = g.s0 - ((float)x + 0.5f);"),
        (KP, "const float dy = g.s1 - (float)y;", "const float dy = g.s1 - ((float)y + 0.5f);"),
        (RP, "dx = f32(xy[0]) - xs.astype(f32)", "dx = f32(xy[0]) - (xs.astype(f32) + f32(0.5))"),
        (RP, "dy = f32(xy[1]) - ys.astype(f32)", "dy = f32(xy[1]) - (ys.astype(f32) + f32(0.5))")]),
    Mutant("P04", "rpws", "both", "transmission 1 - alpha instead of sqrt(1 - alpha)", [
        (KP, "*dst = sqrt(1.0f - alpha) * (*dst)", "*dst = (1.0f - alpha) * (*dst)"),
        (RP, "u[y0:y1, x0:x1] = reference.composite_layer(\n"
             "                        u[y0:y1, x0:x1], np.float32(color[k, c]), alphas[k], phi)",
         "u[y0:y1, x0:x1] = (1.0 - alphas[k]) * u[y0:y1, x0:x1] + np.sqrt(\n"
         "                        np.float32(color[k, c]) * alphas[k]) * "
         "np.exp(1j * phi.astype(np.float64))")]),
    Mutant("P05", "rpws", "ordinary", "host propagates each step by -dz", [
        (HP, "dz = float(self.steps[k])", "dz = -float(self.steps[k])")]),
    Mutant("P06", "rpws", "ordinary", "bounding box end one pixel short (floor(x + r))", [
        (RP, "x1 = np.clip(np.floor(xy[:, 0] + r) + 1, 0, W)",
         "x1 = np.clip(np.floor(xy[:, 0] + r), 0, W)"),
        (RP, "y1 = np.clip(np.floor(xy[:, 1] + r) + 1, 0, H)",
         "y1 = np.clip(np.floor(xy[:, 1] + r), 0, H)")]),
    Mutant("P07", "rpws", "ordinary", "primitives_to_mpi: slabs placed at their near edge", [
        (BP, "centres = d0 + (np.arange(L) + 0.5) / L * (d1 - d0)",
         "centres = d0 + np.arange(L) / L * (d1 - d0)")]),
    Mutant("P08", "rpws", "ordinary",
           "primitives_to_mpi: in-slab colour summed without transmittance", [
        (BP, "premult[s, y0:y1, x0:x1] += (a * tr)[..., None] * primitives.color[k]",
         "premult[s, y0:y1, x0:x1] += a[..., None] * primitives.color[k]")]),
    Mutant("P09", "rpws", "ordinary", "metric_depths: nearest primitive mapped to far", [
        (BP, "t = (inv.max() - inv) / span", "t = (inv - inv.min()) / span")]),
    # ------------------------------------------------------------------ splat rasteriser
    Mutant("S01", "splats", "both", "slab colour left premultiplied (C, not C / alpha_d)", [
        (KS, "                    vstore3(C / a, cur * npix + pix, out_color);",
         "                    vstore3(C, cur * npix + pix, out_color);"),
        (KS, "        out_alpha[cur * npix + pix] = a;\n"
             "        vstore3(C / a, cur * npix + pix, out_color);",
         "        out_alpha[cur * npix + pix] = a;\n"
         "        vstore3(C, cur * npix + pix, out_color);"),
        (SP, "color_out[s, cy, cx] = C[cy, cx] / a[:, None]", "color_out[s, cy, cx] = C[cy, cx]")]),
    Mutant("S02", "splats", "both",
           "in-slab colour weighted by the total, not the slab, transmittance", [
        (KS, "C += s_rgb[j].xyz * (alpha * Ts);", "C += s_rgb[j].xyz * (alpha * T);"),
        (SP, "(al * Ts[ly, lx])[:, None]", "(al * T[ly, lx])[:, None]")]),
    Mutant("S03", "splats", "both", "early stop tested on T before this splat, not after", [
        (KS, "if (test_T < t_min) {", "if (T < t_min) {"),
        (SP, "stop = live & (test_T < t_min)", "stop = live & (T[ys, xs] < t_min)")]),
    Mutant("S04", "splats", "ordinary", "EWA dilation added to the x variance only", [
        (SP, "c = cov[:, 1, 1] + dilation", "c = cov[:, 1, 1]")]),
    Mutant("S05", "splats", "ordinary", "3-sigma radius from the smaller eigenvalue", [
        (SP, "lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))",
         "lam = mid - np.sqrt(np.maximum(0.1, mid * mid - det))")]),
    Mutant("S06", "splats", "ordinary", "slab depth at the slab's edge, not its centre", [
        (SP, "mids = e0 + (np.arange(slabs) + 0.5) / slabs * (e1 - e0)",
         "mids = e0 + np.arange(slabs) / slabs * (e1 - e0)")]),
    Mutant("S07", "splats", "ordinary", "conic off-diagonal +b/det instead of -b/det", [
        (SP, "conic=np.stack([c[sel] * inv[sel], -b[sel] * inv[sel], a[sel] * inv[sel]],",
         "conic=np.stack([c[sel] * inv[sel], b[sel] * inv[sel], a[sel] * inv[sel]],")]),
    Mutant("S08", "splats", "ordinary", "exp-skip floor margin on the wrong side", [
        (SP, "floor = np.log(1.0 / (255.0 * o)) - 1e-5",
         "floor = np.log(1.0 / (255.0 * o)) + 1e-5")]),
    Mutant("S09", "splats", "ordinary", "slab colour not decoded from sRGB to linear", [
        (SP, "color = srgb_to_linear(np.clip(color, 0.0, 1.0)).astype(np.float32)",
         "color = np.clip(color, 0.0, 1.0).astype(np.float32)")]),
    # ------------------------------------------------------------------ MPI recursion
    Mutant("C01", "composite", "both", "emission amplitude c*a (sqrt dropped)", [
        (KC, "const float amp = sqrt(color[(size_t)p * n_channels + channel] * a);",
         "const float amp = color[(size_t)p * n_channels + channel] * a;"),
        (KC, "const float4 amp = sqrt(col * a);", "const float4 amp = col * a;"),
        (KCS, "const float amp = sqrt(color[(size_t)p * n_channels + c] * a);",
         "const float amp = color[(size_t)p * n_channels + c] * a;"),
        (KCS, "const float4 amp = sqrt(col4 * a);", "const float4 amp = col4 * a;"),
        (KCS, "const float16 amp = sqrt((float16)(co[j], co[j + 4]) * al);",
         "const float16 amp = (float16)(co[j], co[j + 4]) * al;"),
        (KCB, "vstore8(sqrt(vload8(0, lanes) * a), 0,", "vstore8(vload8(0, lanes) * a, 0,"),
        (R0, "amp = np.sqrt(c_pad * a_pad[..., None])", "amp = c_pad * a_pad[..., None]"),
        (R0, "np.sqrt(c * a) * np.exp(", "(c * a) * np.exp(")]),
    Mutant("C02", "composite", "both", "transmission 1 - a instead of sqrt(1 - a)", [
        (KC, "#define CLHOLO_TRANSMISSION(a) sqrt(1.0f - (a))",
         "#define CLHOLO_TRANSMISSION(a) (1.0f - (a))"),
        (KCS, "const float keep = sqrt(1.0f - a);", "const float keep = (1.0f - a);"),
        (KCS, "const float4 keep = sqrt(1.0f - a);", "const float4 keep = (1.0f - a);"),
        (KCS, "const float16 keep = sqrt(1.0f - al);", "const float16 keep = (1.0f - al);"),
        (KCB, "vstore8(sqrt(1.0f - a), 0, keep", "vstore8((1.0f - a), 0, keep"),
        (R0, "keep = np.sqrt(np.float32(1) - a_pad)", "keep = np.float32(1) - a_pad"),
        (R0, "np.sqrt(1.0 - a) * u", "(1.0 - a) * u")]),
    Mutant("C03", "composite", "ordinary", "fused store draws the phases of layer i, not i - 1", [
        (SCH, "np.uint32(i - 1), np.uint32(frame0), self.key[0], self.key[1]]\n",
         "np.uint32(i), np.uint32(frame0), self.key[0], self.key[1]]\n")]),
    Mutant("C03b", "composite", "ordinary",
           "two-kernel layer's composite draws the phases of layer i, not i - 1", [
        (SCH, "np.uint32(i - 1), np.uint32(frame0), self.key[0], self.key[1]])",
         "np.uint32(i), np.uint32(frame0), self.key[0], self.key[1]])")]),
    Mutant("C04", "composite", "ordinary",
           "layer steps start at d_0 (last step does not reach z = 0)", [
        (R0, "return np.diff(np.concatenate([[0.0], d]))",
         "return np.diff(np.concatenate([[d[0]], d]))")]),
    Mutant("C05", "composite", "ordinary", "nearest layer taken as the farthest (farthest flag)", [
        (SCH, "self._launch_composite(field.data, i, frame0, frames, farthest=i == L - 1)",
         "self._launch_composite(field.data, i, frame0, frames, farthest=i == 0)")]),
    Mutant("C07", "rgbd", "ordinary",
           "layer sum propagates each layer by its step, not its depth", [
        (SCH, "tf = self._tf_cache.get(self.queue, self.padded, float(self.mpi.depths[i]),",
         "tf = self._tf_cache.get(self.queue, self.padded, float(self.steps[i]),")]),
    Mutant("C08", "rgbd", "ordinary", "layer-sum padding sized for the steps, not the depths", [
        (SCH, "spans = self.steps if self.occlusion else mpi.depths", "spans = self.steps")]),
    Mutant("C09", "composite", "ordinary",
           "CPU layer blocks: every colour reads colour 0's amplitudes", [
        (KCS, "__global const float *ap = color + layer_block_at(row0, col, width, n_channels, c);",
         "__global const float *ap = color + layer_block_at(row0, col, width, n_channels, 0);")],
           tests=["tests/test_layer_blocks.py", "tests/test_hologram_two_pass.py"]),
    Mutant("C10", "composite", "ordinary",
           "CPU layer blocks: a black half-transparent block skipped as transparent", [
        (KCS, "visible = fmax(visible, fmax(co[j], 1.0f - a[j]));",
         "visible = fmax(visible, co[j]);")],
           tests=["tests/test_layer_blocks.py", "tests/test_hologram_two_pass.py"]),
    Mutant("C11", "composite", "ordinary",
           "sin/cos quadrant rounded with an odd constant (rint's ties go to odd quadrants)", [
        ("kernels/fast_sincos.h", "#define CLHOLO_QUADRANT(y) (((y) + 12582912.0f) - 12582912.0f)",
         "#define CLHOLO_QUADRANT(y) (((y) + 12582911.0f) - 12582911.0f)")],
           tests=["tests/test_fast_sincos.py"]),
    Mutant("C12", "composite", "ordinary",
           "GPU layer planes: every colour reads colour 0's amplitudes", [
        (KCS, "const float4 amp = vload4(0, color + layer_block_at(row, col, width, n_channels, c));",
         "const float4 amp = vload4(0, color + layer_block_at(row, col, width, n_channels, 0));")],
           tests=["tests/test_layer_blocks.py", "tests/test_gpu_mid_quads.py"]),
    Mutant("C13", "composite", "ordinary",
           "GPU mid step by quads: a quad taken across the frame's rows, not along one", [
        ("kernels/fft_gpu.cl", "const int dl = MID_QUAD_DL, dk = 1 - MID_QUAD_DL;",
         "const int dl = 1 - MID_QUAD_DL, dk = MID_QUAD_DL;")],
           tests=["tests/test_gpu_mid_quads.py"]),
    # ------------------------------------------------------------------ ASM
    Mutant("A01", "asm", "both", "band limit without the factor 2 in (2 df dz)^2", [
        (PROP, "return [1.0 / (lam * math.sqrt((2.0 * dz / (n * pitch)) ** 2 + 1.0)) "
               "for lam in lams]",
         "return [1.0 / (lam * math.sqrt((dz / (n * pitch)) ** 2 + 1.0)) for lam in lams]"),
        (R0, "limit_y = 1.0 / (wavelength * math.sqrt((2.0 * dz / (H * pitch)) ** 2 + 1.0))",
         "limit_y = 1.0 / (wavelength * math.sqrt((dz / (H * pitch)) ** 2 + 1.0))"),
        (R0, "limit_x = 1.0 / (wavelength * math.sqrt((2.0 * dz / (W * pitch)) ** 2 + 1.0))",
         "limit_x = 1.0 / (wavelength * math.sqrt((dz / (W * pitch)) ** 2 + 1.0))")]),
    Mutant("A02", "asm", "both", "carrier phase -2 pi dz / lambda", [
        (PROP, "[math.fmod(2.0 * math.pi * dz / lam, 2.0 * math.pi) for lam in lams]",
         "[math.fmod(-2.0 * math.pi * dz / lam, 2.0 * math.pi) for lam in lams]"),
        (R0, "carrier = math.fmod(2.0 * math.pi * dz / wavelength, 2.0 * math.pi)",
         "carrier = math.fmod(-2.0 * math.pi * dz / wavelength, 2.0 * math.pi)")]),
    Mutant("A03", "asm", "both", "phase remainder pi dz f^2/... (factor 2 dropped)", [
        (PROP, "np.uint32(C), np.float64(2.0 * math.pi * dz))",
         "np.uint32(C), np.float64(math.pi * dz))"),
        (R0, "rest = -2.0 * math.pi * dz * f2 / (1.0 / wavelength + root)",
         "rest = -math.pi * dz * f2 / (1.0 / wavelength + root)")]),
    Mutant("A04", "asm", "ordinary", "frequency steps 1/(Hp p) and 1/(Wp p) swapped", [
        (PROP, "np.float64(1.0 / (Hp * pitch)), np.float64(1.0 / (Wp * pitch)), dconsts.data,",
         "np.float64(1.0 / (Wp * pitch)), np.float64(1.0 / (Hp * pitch)), dconsts.data,")]),
    Mutant("A05", "asm", "ordinary", "band limits of x and y swapped", [
        (PROP, "limits(Hp), limits(Wp)], dtype=np.float64)",
         "limits(Wp), limits(Hp)], dtype=np.float64)")]),
    Mutant("A06", "asm", "ordinary", "mirror row Hp - y - 1 (off by one)", [
        (KA, "const uint ym = (y == 0u) ? y : Hp - y;",
         "const uint ym = (y == 0u) ? y : Hp - y - 1u;")]),
    Mutant("A07", "asm", "both",
           "Fresnel (paraxial) remainder f^2 lambda / 2 instead of the exact root", [
        (KA, "TF_REAL4 phase = consts[C + c] - two_pi_dz * f2 / (il + root);",
         "TF_REAL4 phase = consts[C + c] - two_pi_dz * f2 / (il + il);"),
        (R0, "rest = -2.0 * math.pi * dz * f2 / (1.0 / wavelength + root)",
         "rest = -2.0 * math.pi * dz * f2 / (2.0 / wavelength)")]),
    Mutant("A08", "asm", "ordinary",
           "even factors strip by strip read line c unfolded (the upper half's lines)", [
        ("kernels/fft_cpu.cl", "src[src_off + f * frame + FFT_EVEN_INDEX(c, nlines) * ls + k * es]",
         "src[src_off + f * frame + c * ls + k * es]")],
           tests=["tests/test_propagation_three_pass.py", "tests/test_fft_round_trip.py"]),
    Mutant("A09", "asm", "ordinary",
           "padded half skipped: radix-4 first stage of a half-zero input with -i for +i", [
        ("kernels/fft_common.h", "(a1) = x_ + n_; (a3) = x_ - n_; }",
         "(a1) = x_ - n_; (a3) = x_ + n_; }")],
           tests=["tests/test_propagation.py", "tests/test_fft_pruned.py"]),
    Mutant("A10", "asm", "ordinary",
           "cropped half skipped where it is read: the rule N / 2 + 1 outputs", [
        ("kernels/fft_cpu.cl", "8 * p == N && 2 * nout <= N)",
         "8 * p == N && 2 * nout <= N + 2)")],
           tests=["tests/test_propagation.py", "tests/test_fft_pruned.py"]),
    # ------------------------------------------------------------------ metrics
    Mutant("M01", "metrics", "ordinary", "scale fit divides by <R, R> instead of <I, I>", [
        (MET, "den = float(np.sum(image * image))", "den = float(np.sum(reference * reference))")]),
    Mutant("M02", "metrics", "ordinary", "default data range max - min instead of the maximum", [
        (MET, "data_range = float(ref.max())\n", "data_range = float(ref.max() - ref.min())\n")]),
    Mutant("M03", "metrics", "ordinary", "per-colour gains divide instead of multiply", [
        (MET, "test = img * np.asarray(scales)", "test = img / np.asarray(scales)")]),
    Mutant("M04", "metrics", "ordinary", "per-colour fit against colour 0 of the reference", [
        (MET, "scales.append(scale_fit(img[..., c], ref[..., c]))",
         "scales.append(scale_fit(img[..., c], ref[..., 0]))")]),
    # ------------------------------------------------------------------ RGB-D baseline
    Mutant("G01", "rgbd", "both", "layer sum propagates each layer by -d_i", [
        (SCH, "tf = self._tf_cache.get(self.queue, self.padded, float(self.mpi.depths[i]),",
         "tf = self._tf_cache.get(self.queue, self.padded, -float(self.mpi.depths[i]),"),
        (RB, "reference.propagate(v, float(depths[i]),",
         "reference.propagate(v, -float(depths[i]),")]),
    Mutant("G02", "rgbd", "ordinary", "hard depth bins by floor instead of the nearest plane", [
        ("clholo/io/rgbd.py", "idx = np.clip(np.rint(s).astype(int), 0, L - 1)",
         "idx = np.clip(np.floor(s).astype(int), 0, L - 1)")]),
]


# ----------------------------------------------------------------------------------------------
def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def restore(files: Sequence[str]) -> None:
    if files:
        r = _git("checkout", "--", *sorted(set(files)))
        if r.returncode != 0:
            print(f"!! git checkout failed: {r.stderr}", file=sys.stderr)


def check_clean(files: Sequence[str]) -> None:
    r = _git("status", "--porcelain", "--", *sorted(set(files)))
    if r.stdout.strip():
        sys.exit(f"refusing to run: files the mutants edit have uncommitted changes "
                 f"(git checkout would discard them):\n{r.stdout}")


def apply(m: Mutant) -> Optional[str]:
    """Apply the edits in place; an error message (and nothing applied) when a find text does
    not occur exactly once."""
    texts = {}
    for path, find, repl in m.edits:
        text = texts.get(path)
        if text is None:
            text = (ROOT / path).read_text(encoding="utf-8")
        n = text.count(find)
        if n != 1:
            return f"{path}: find text occurs {n} times: {find[:60]!r}"
        texts[path] = text.replace(find, repl)
    for path, text in texts.items():
        (ROOT / path).write_text(text, encoding="utf-8")
    return None


def wait_for_lock() -> None:
    announced = False
    while LOCK.exists():
        if not announced:
            print(f"   waiting: {LOCK} exists (timings in progress)", flush=True)
            announced = True
        time.sleep(20)


BUILD_ERROR = re.compile(r"ProgramBuildError|BUILD_PROGRAM_FAILURE|clBuildProgram failed|"
                         r"SyntaxError|IndentationError")


def run_selection(m: Mutant, timeout: float, python: str) -> Tuple[str, str, float]:
    """(status, first failing test or note, seconds)."""
    cmd = [python, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *m.selection()]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return "timeout", f"ran past {timeout:.0f} s", time.monotonic() - t0
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    dt = time.monotonic() - t0
    if proc.returncode == 0:
        return "missed", "", dt
    failed = re.findall(r"^(?:FAILED|ERROR) (.+?)(?: - .*)?$", out, re.M)
    if BUILD_ERROR.search(out):
        return "broken", (failed[0] if failed else "build error"), dt
    if proc.returncode in (1,) and failed:
        return "caught", failed[0], dt
    if proc.returncode < 0 or proc.returncode > 128:
        return "caught", f"test process crashed (exit {proc.returncode})", dt
    tail = out.strip().splitlines()[-3:]
    return "broken", f"pytest exit {proc.returncode}: {' | '.join(tail)}", dt


def _short(test_id: str) -> str:
    """``tests/test_x.py::test_name[params]`` -> ``test_x.py::test_name``."""
    return re.sub(r"\[.*\]$", "", test_id.replace("tests/", ""))


def summarise(rows) -> str:
    counted = [r for r in rows if r["status"] in ("caught", "missed", "timeout")]
    both = [r for r in counted if r["kind"] == "both"]
    ordinary = [r for r in counted if r["kind"] == "ordinary"]

    def rate(rs):
        k = sum(r["status"] != "missed" for r in rs)
        return f"{k} of {len(rs)} ({100.0 * k / len(rs):.0f} %)" if rs else "none"

    return (f"overall {rate(counted)}; ordinary {rate(ordinary)}; both {rate(both)}; "
            f"not counted: {len(rows) - len(counted)}")


def write_results(rows, stem: Path, started: str) -> None:
    stem.parent.mkdir(parents=True, exist_ok=True)
    keys = ["id", "family", "kind", "change", "status", "caught_by", "seconds"]
    with open(stem.with_suffix(".csv"), "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in keys})
    lines = [f"# Mutation campaign, {started}", "", summarise(rows), "",
             "| id | family | kind | change | result | caught by |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['id']} | {r['family']} | {r['kind']} | {r['change']} | "
                     f"{r['status']} | {_short(r['caught_by'])} |")
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", help="comma-separated mutant ids")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per mutant (300)")
    ap.add_argument("--out", default=str(ROOT / "tests" / "mutation" / "results"),
                    help="stem of the .csv and .md results (default tests/mutation/results)")
    ap.add_argument("--check", action="store_true",
                    help="only check that every find text occurs exactly once")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("--python", default=sys.executable, help="interpreter that runs pytest")
    args = ap.parse_args(argv)

    ids = [m.id for m in MUTANTS]
    assert len(ids) == len(set(ids)), "duplicate mutant ids"
    chosen = MUTANTS
    if args.only:
        want = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = sorted(set(want) - set(ids))
        if unknown:
            sys.exit(f"unknown mutant id(s): {', '.join(unknown)}")
        chosen = [m for m in MUTANTS if m.id in want]
    if args.list:
        for m in chosen:
            print(f"{m.id:4} {m.family:9} {m.kind:8} {m.change}")
        return 0
    files = sorted({e[0] for m in chosen for e in m.edits})
    if args.check:  # reads the files only: a tree with edits (or a copied one) may be checked
        bad = 0
        for m in chosen:
            for path, find, _ in m.edits:
                n = (ROOT / path).read_text(encoding="utf-8").count(find)
                if n != 1:
                    bad += 1
                    print(f"{m.id}: {path}: occurs {n} times: {find[:70]!r}")
            if m.kind == "both" and not (any(e[0] in REFERENCES or
                                                 e[0].startswith("clholo/reference/")
                                                 for e in m.edits)
                                             and any(not e[0].startswith("clholo/reference/")
                                                     for e in m.edits)):
                bad += 1
                print(f"{m.id}: kind 'both' needs an edit of a reference and one outside it")
        print(f"{len(chosen)} mutants ({sum(m.kind == 'both' for m in chosen)} 'both'), "
              f"{bad} problem(s)")
        return 1 if bad else 0
    check_clean(files)  # the mutants edit files in place and restore them with git checkout

    def on_term(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, on_term)

    started = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    rows = []
    try:
        for m in chosen:
            wait_for_lock()
            touched = [e[0] for e in m.edits]
            try:
                err = apply(m)
                if err:
                    status, note, dt = "invalid", err, 0.0
                else:
                    status, note, dt = run_selection(m, args.timeout, args.python)
            finally:
                restore(touched)
            rows.append(dict(id=m.id, family=m.family, kind=m.kind, change=m.change,
                             status=status, caught_by=note, seconds=f"{dt:.1f}"))
            print(f"{m.id:4} {m.kind:8} {status:8} {dt:6.1f}s  {_short(note)}", flush=True)
            write_results(rows, Path(args.out), started)
    except KeyboardInterrupt:
        print("interrupted: files restored, partial results written", file=sys.stderr)
        write_results(rows, Path(args.out), started)
        return 130
    print(summarise(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
