"""A trained run's files, checked before anything uses them: the config, the checkpoint, the dataset and the run
manifest (:mod:`.manifest`: the legend, posteriors and dataset files the run was trained with). Training writes the
manifest; ``physgs export``, the viewer and ``physgs batch`` check it. This package imports neither the nerfstudio
integration nor the exporters, so both can call it."""
