"""Lifting 2D evidence (material maps) onto 3D Gaussians through their alpha-blending weights."""

from .lift import LiftResult, group_views, label_evidence_maps, lift_evidence, lift_views

__all__ = ["LiftResult", "group_views", "label_evidence_maps", "lift_evidence", "lift_views"]
