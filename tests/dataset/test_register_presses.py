"""Which presses register a store: the registration presses, joined by the grid's when too few of
theirs are found (faint contacts on a noisy unit)."""

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from threedcal.dataset.build import _register_presses
from threedcal.errors import RegistrationError

# plan rows: 2 touch-search rows, then pairs of a paused registration press and its grid press
PHASE = np.array(["touch", "touch"] + ["register", "grid"] * 10)
REGISTER = np.flatnonzero(PHASE == "register")


def locator(found_in_register: int, phase=PHASE):
    """A stand-in for the registration: finds `found_in_register` of the registration presses'
    contacts and every grid press's, and records which rows it was asked for."""
    asked = []

    def located(rows, whole, progress):
        asked.append(np.asarray(rows))
        contacts = []
        seen = 0
        for row in rows:
            if phase[row] == "register":
                seen += 1
                contacts.append(object() if seen <= found_in_register else None)
            else:
                contacts.append(object())
        if sum(c is not None for c in contacts) < 3:
            raise RegistrationError("registration needs >= 3 contacts not on one line")
        return SimpleNamespace(contacts=contacts)

    return located, asked


@pytest.mark.parametrize("found", [5, 10])
def test_enough_registration_contacts_register_alone(found, caplog):
    located, asked = locator(found)
    with caplog.at_level(logging.WARNING):
        registration, rows = _register_presses(located, PHASE, REGISTER, None, False)
    np.testing.assert_array_equal(rows, REGISTER)
    assert len(asked) == 1 and sum(c is not None for c in registration.contacts) == found
    assert not caplog.records


@pytest.mark.parametrize("found", [0, 2, 4])
def test_too_few_registration_contacts_are_joined_by_the_grid_presses(found, caplog):
    """5 needed: 0-2 found is too few for any affine (an error before), 4 a fit with nothing to
    spare; the grid presses join them, and the log says how many were found."""
    located, asked = locator(found)
    with caplog.at_level(logging.WARNING):
        registration, rows = _register_presses(located, PHASE, REGISTER, None, False)
    np.testing.assert_array_equal(rows, np.arange(2, len(PHASE)))
    # asked twice: the registration presses alone, then with the grid's
    assert [list(a) for a in asked] == [list(REGISTER), list(rows)]
    assert sum(c is not None for c in registration.contacts) == found + 10
    (record,) = caplog.records
    assert "the 10 registration presses located" in record.getMessage()
    assert "5 needed" in record.getMessage() and "10 grid presses together" in record.getMessage()


def test_a_plan_without_registration_presses_registers_on_its_grid():
    phase = np.array(["touch"] + ["grid"] * 6)
    located, asked = locator(0, phase)
    grid = np.flatnonzero(phase == "grid")
    _, rows = _register_presses(located, phase, grid, None, False)
    np.testing.assert_array_equal(rows, grid)
    assert len(asked) == 1


def test_no_grid_press_yet_keeps_the_registration_presses_error():
    phase = np.array(["touch"] + ["register"] * 6)
    located, _ = locator(2, phase)
    with pytest.raises(RegistrationError):
        _register_presses(located, phase, np.flatnonzero(phase == "register"), None, False)
