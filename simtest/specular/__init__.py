"""Phong's specular model and the endoscopic isocurves (paper eqs. 1-3, Propositions 1 and 2); the film's Fresnel term."""

from simtest.specular.phong import (endoscopic_isocurve, general_isocurve, isocurve_radii, isophote_radius,
                                   kappa_from_isovalue, phong_intensity, tau_from_isovalue)

__all__ = ["endoscopic_isocurve", "general_isocurve", "isocurve_radii", "isophote_radius", "kappa_from_isovalue",
           "phong_intensity", "tau_from_isovalue"]
