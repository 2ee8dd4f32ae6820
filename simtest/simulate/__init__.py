"""Analytic images: closed-form Phong renders of planes, and the paper's synthetic protocol."""
