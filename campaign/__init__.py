"""Whole pipelines and test campaigns on top of identify, signaldesign and cueing."""
