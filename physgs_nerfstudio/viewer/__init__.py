"""The viewer as a measuring instrument (docs/viewer.md): fixed-scale property outputs that colour only what
perception measured (:mod:`.display`, :mod:`.scales`), the click query (:mod:`.query`), selection-to-mass with
`physgs export`'s own computation (:mod:`.mass`) and the "Physical properties" panel (:mod:`.panel`, nerfstudio
viewer elements). Import submodules directly: :mod:`.panel` needs nerfstudio's viewer, the others do not."""
