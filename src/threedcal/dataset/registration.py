"""Registration: contact centres from the probe frames themselves → the printer-mm → pixel map.

Every probe frame votes: its contact is located by its rim (threedcal.dataset.contacts) and, where
the gel allows, by its mirror symmetry (threedcal.dataset.symmetry); on a domed gel each centre is
moved from its contact to its press's axis (threedcal.dataset.dome_contacts); the affine, and with
enough contacts the lens, are fitted to them (threedcal.dataset.camera_fit). The locator whose
centres the fit maps best is kept.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from threedcal.dataset.camera_fit import (
    MIN_LENS_CONTACTS,
    AffineFit,
    fit_affine,
    fit_camera,
    fit_lensed,
)
from threedcal.dataset.contacts import Contact, locate_contact
from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.dataset.symmetry import SymmetryRefinement, refine_by_symmetry
from threedcal.errors import RegistrationError
from threedcal.lens import RadialLens


@dataclass(frozen=True)
class CameraRegistration:
    """The affine of the chosen contact locator, and what the choice rested on."""

    fit: AffineFit
    contacts: list[Contact | None]  # per input frame, from the chosen locator
    locator: str  # "rim" or "symmetry"
    residual_px: dict[str, float]  # affine RMS residual of each locator that produced a fit
    unmixing: np.ndarray | None  # the symmetry locator's channel unmixing (None: not run)
    # where the kept symmetric fits started: "rim" (its centres) or "fit" (where the first pass's
    # affine places each press); None: the symmetry locator did not run
    symmetry_start: str | None = None


def register_camera(
    xy_mm: np.ndarray,
    frames,
    blank: np.ndarray,
    accept=lambda contact: True,
    flat_gel: bool = True,
    progress: bool = False,
    lens: bool | RadialLens = False,
    dome: DomedContacts | None = None,
) -> CameraRegistration:
    """Locate the contact in every frame by rim and, on a flat gel, by symmetry; fit the affine
    (and with `lens`, the camera lens's radial distortion with it: `fit_lensed`; given a
    RadialLens, the sensor profile's, from it: `fit_camera` chooses how much of it to refit).

    The rim locator's bias drifts across the frame and the affine absorbs it as a scale. The
    symmetry locator has no such drift on a flat gel. On a domed gel every contact leans toward the
    apex; with `dome` (DomedContacts) each centre is moved from its contact to its press's axis —
    the rim's by the rigid overlap's centroid, the symmetric one (run only where the gel is
    elastic, `dome.elastic`) by the elastic pressure's. Where the gel follows the ball
    (`flat_gel=False` without an elastic `dome`), the shading of the domed blank's slope shifts
    symmetric centres radially by up to a pixel, an error an affine absorbs unseen: only the rim
    is used. Where both run, the locator whose centres an affine maps with the smaller RMS
    residual is kept (a failing
    unmixing or a clipped sensor shows there). `accept(contact)` drops contacts (e.g. too near
    the image edge) before fitting.

    A lens bends each contact, so its located centre is not where the lens images the press's
    axis (on the DIGIT's lens a contact 70 px across is off by up to 0.4 px near the frame's edge).
    With `lens`, a first fit (principal point and κ₁) rectifies the frames; the contacts are
    located again there, where they are round, mapped back through it, and the lens refitted to
    them (docs/explanation/registration.md, The lens).
    """
    shape = np.shape(blank)[:2] if lens is not False else None
    prior = lens if isinstance(lens, RadialLens) else None
    fitting = (shape, prior)
    located = _locate_and_fit(xy_mm, frames, blank, accept, flat_gel, progress, fitting, dome=dome)
    if not lens:
        return located
    first = located.fit.lens
    if first is None:  # too few contacts for the lens
        return located
    again = _locate_and_fit(
        xy_mm,
        [first.rectify(np.asarray(f)) for f in frames],
        first.rectify(np.asarray(blank, dtype=np.float32)),
        accept,
        flat_gel,
        progress,
        fitting,
        back=first,
        dome=dome,
    )
    return again


def _locate_and_fit(
    xy_mm, frames, blank, accept, flat_gel, progress, fitting, back=None, dome=None
):
    """One pass of `register_camera`. `back`: the frames were rectified through this lens; the contacts
    are mapped back through it to camera pixels before the fit."""

    def unbent(contacts):
        if back is None:
            return contacts
        out = []
        for c in contacts:
            if c is not None:
                x, y = back.distort(np.array([c.x_px, c.y_px]))
                c = Contact(float(x), float(y), c.radius_px, c.strength)
            out.append(c)
        return out

    rim = [
        locate_contact(np.asarray(f), blank)
        for f in tqdm(frames, desc="rim centres", unit="frame", disable=not progress)
    ]
    rim = [c if c is not None and accept(c) else None for c in rim]

    def on_axis(contacts, model):  # on a dome: each centre moved from its contact to its axis
        return contacts if dome is None else dome.to_axis(contacts, model)

    unmixing = None
    contacts = unbent(on_axis(rim, "area"))
    candidates = {"rim": (contacts, _fit_contacts(xy_mm, contacts, *fitting))}
    symmetry_start = None
    # the symmetric centre of a contact on a dome: where an elastic layer's pressure is centred
    by_symmetry = flat_gel if dome is None else dome.elastic
    if by_symmetry and np.ndim(blank) == 3 and sum(c is not None for c in rim) >= 3:
        refined = refine_by_symmetry(frames, blank, rim, progress=progress)
        unmixing = refined.unmixing
        symmetric = [c if c is not None and accept(c) else None for c in refined.contacts]
        if sum(c is not None for c in symmetric) >= 3:
            contacts = unbent(on_axis(symmetric, "pressure"))
            candidates["symmetry"] = (contacts, _fit_contacts(xy_mm, contacts, *fitting))
            symmetry_start = "rim"
            again = _symmetry_from_fit(
                xy_mm, frames, blank, rim, candidates["symmetry"][1], accept, back, progress, dome
            )
            if sum(c is not None for c in again.contacts) >= 3:
                contacts = unbent(on_axis(again.contacts, "pressure"))
                fit = _fit_contacts(xy_mm, contacts, *fitting)
                if fit.residual_px < candidates["symmetry"][1].residual_px:
                    candidates["symmetry"] = (contacts, fit)
                    unmixing, symmetry_start = again.unmixing, "fit"
    locator = min(candidates, key=lambda name: candidates[name][1].residual_px)
    contacts, fit = candidates[locator]
    return CameraRegistration(
        fit=fit,
        contacts=contacts,
        locator=locator,
        residual_px={name: fit.residual_px for name, (_, fit) in candidates.items()},
        unmixing=unmixing,
        symmetry_start=symmetry_start,
    )


def _symmetry_from_fit(
    xy_mm, frames, blank, rim, fit: AffineFit, accept, back, progress, dome=None
) -> SymmetryRefinement:
    """The symmetry locator again, each fit started where `fit` places its press.

    The symmetric fit's cost can have a second minimum a few pixels from the true centre. On an
    elastic gel, whose shading halo reaches well past the rim, the rim locator's centre lies 2-3 px
    off near the frame's edges and the fit started there can settle in that minimum (a lower cost
    than the true one's for about half the contacts within 30-45 px of the Mini's edge). A lattice
    of presses knows better where each contact is: the affine (and lens) of the first pass, fitted
    over every contact, places each within a fraction of a pixel, and the fit started there stays
    in the true minimum (docs/explanation/registration.md, Symmetric centres on an elastic gel)."""
    guess = fit.apply(np.asarray(xy_mm, dtype=np.float64))
    if back is not None:  # the frames are rectified: start where the ideal frame holds each press
        guess = back.undistort(guess)
    if dome is not None:  # ... at its contact's centre, off the axis toward the dome's apex
        guess = dome.contacts_at(guess, "pressure")
    starts = [
        None if c is None else Contact(float(g[0]), float(g[1]), c.radius_px, c.strength)
        for c, g in zip(rim, guess, strict=True)
    ]
    refined = refine_by_symmetry(frames, blank, starts, progress=progress, anchors=rim)
    return SymmetryRefinement(
        contacts=[c if c is not None and accept(c) else None for c in refined.contacts],
        unmixing=refined.unmixing,
    )


def _fit_contacts(
    xy_mm: np.ndarray, contacts: list[Contact | None], lens_shape=None, prior=None
) -> AffineFit:
    """fit_affine (or, given the frames' `lens_shape`, fit_lensed; and a `prior` lens,
    fit_camera) over all frames; a frame without a contact is a non-finite point, never an
    inlier."""
    xy_px = np.array([(c.x_px, c.y_px) if c is not None else (np.nan, np.nan) for c in contacts])
    found = sum(c is not None for c in contacts)
    if lens_shape is not None:
        try:
            if prior is not None:
                return fit_camera(xy_mm, xy_px.reshape(-1, 2), lens_shape, prior)
            if found >= MIN_LENS_CONTACTS:
                return fit_lensed(xy_mm, xy_px.reshape(-1, 2), lens_shape)
        except RegistrationError:  # outliers left too few: as too few found
            pass
        logging.getLogger(__name__).warning(
            "registration: %d contacts, fewer than the %d inliers a lens fit needs: the affine "
            "alone (the lens's distortion stays in the frames; probe a denser plan to remove it)",
            found,
            MIN_LENS_CONTACTS,
        )
    return fit_affine(xy_mm, xy_px.reshape(-1, 2))
