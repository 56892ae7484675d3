"""Parametric biventricular phantoms with known ground truth (issue 3).

Public API::

    from cardionurbs import phantom
    ph = phantom.generate("normal", seed=0, frames=20)     # -> Phantom (.study, .truth, model)
    phantom.write_phantom(ph, "out/normal_000", dicom=True) # study.json, points.csv, dicom/, truth.json
    subjects = phantom.load_cohort_spec(phantom.presets.data_path("paper12.toml"))
    phantom.generate_cohort(subjects, "out/paper12")

Modules: anatomy (ED shapes), motion (analytic volume-preserving map),
presets (TOML presets, sampling, cohort specs), geometry (scanner pose and
imaging planes), annotate (contours, landmarks, tag lines), faults, truth
(ground-truth metrics by two independent methods), dicom (synthetic tagged
DICOM), generate, cli. Nothing here imports the reconstruction code.
"""

from cardionurbs.phantom.generate import Phantom, generate, generate_cohort, write_phantom
from cardionurbs.phantom.presets import (PATHOLOGIES, SubjectSpec, load_cohort_spec, load_preset)

__all__ = ["Phantom", "generate", "generate_cohort", "write_phantom", "load_cohort_spec",
           "load_preset", "SubjectSpec", "PATHOLOGIES"]
