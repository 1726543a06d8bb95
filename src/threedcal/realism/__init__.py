"""The simulator held against real frames: its optics fitted to them (fit), how far its images are
from a real sensor's (check; one folder's fit-then-compare run: folder), the 2-D shading around a
contact (halo2d), and how real units differ (unit_measure)."""
