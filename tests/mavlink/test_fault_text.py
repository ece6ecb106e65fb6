"""The flight controller's fault announcement (m4.fault_text) reads back as the fault it states."""

from __future__ import annotations

import pytest

from m4.fault_kind import INJECTABLE, FaultKind
from m4.fault_text import AnnouncedFault, fault_text, read_fault_text


@pytest.mark.parametrize("kind", INJECTABLE)
@pytest.mark.parametrize("rotor", [0, 1, 4])
def test_every_injectable_fault_reads_back(rotor, kind):
    loss = 1.0 if kind in (FaultKind.MOTOR, FaultKind.PROPELLER) else 0.35
    assert read_fault_text(fault_text(rotor, loss, kind)) == AnnouncedFault(rotor, loss, kind)


def test_a_restore_reads_back_as_no_loss():
    assert read_fault_text(fault_text(2, 0.0, FaultKind.MOTOR)) == AnnouncedFault(2, 0.0, FaultKind.DEGRADED)


@pytest.mark.parametrize("text", ["thrust loss rotor 4 (motor)", "FC: rotor 4 lost (ESC speed)", "rotor 9x restored",
                                  "rotor 4 loss 50% injected later"])
def test_other_texts_are_no_fault(text):
    assert read_fault_text(text) is None
