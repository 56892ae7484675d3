"""A programmatic corpus of broken study inputs (see corpus.py)."""
