"""The simulator held against real frames: how far its images are from a real sensor's (check),
the 2-D shading around a contact (halo2d), and how real units differ (unit_measure)."""
