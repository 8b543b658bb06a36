"""Names of PhysGSModel's per-Gaussian tensors in ``gauss_params``, in a leaf module: the model, the pipeline's
lifting and the exporters import them from here."""

from __future__ import annotations

EVIDENCE_KEY = "dirichlet_evidence"
WEIGHT_KEY = "lifting_weight"
LABELLED_KEY = "labelled_weight"
NON_TRAINABLE_KEYS = (EVIDENCE_KEY, WEIGHT_KEY, LABELLED_KEY)
LOGITS_KEY = "material_logits"
FEATURES_KEY = "material_features"
DECODER_GROUP = "material_decoder"
"""optimizer param group (and submodule name) of the "latent" head's decoder"""
