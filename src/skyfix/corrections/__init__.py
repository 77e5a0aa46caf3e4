"""Corrections between the catalogue's directions and the directions a camera sees
(``refraction``: a camera on the ground; docs/frames-and-refraction.md)."""
