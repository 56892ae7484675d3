"""Image geometry: DICOM series, slice planes, pixel <-> scanner."""
