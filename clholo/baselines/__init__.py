"""Baseline hologram methods the paper compares against: the RGB-D layer sum (no occlusion) and random-phase wave splatting of Gaussians (one layer per primitive)."""
