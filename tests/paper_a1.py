"""Appendix A.1 of Park, Burdekin & Peggs, transcribed as printed (OCR slips of notation cleaned).

Each model maps to three expressions (ΔX, ΔY, ΔZ) in the variables ``dI_J`` (µm), ``eI_J`` (µrad),
``alpha, beta1, beta2`` (µrad), ``x, y, z`` (positions from the reference) and ``Xp, Yp, Zp``
(stylus offset), the arms in **metres** so that µrad·m = µm, and ``phi1, phi2`` (µrad/m) for the
horizontal-arm models. Thermal terms are left out here (tested separately, docs/formats.md form).
Transcription source: ../shared/seeds/000_189ae6c983475e5b.txt, appendix A.1. Where the printed
equation disagrees with its kinematic chain, the disagreement is listed in ``CORRECTIONS`` and
explained in docs/seed-equations.md; the expressions below are the paper's, not ours.
"""

SDX = "(dx_x + dx_y + dx_z)"
SDY = "(dy_x + dy_y + dy_z)"
SDZ = "(dz_x + dz_y + dz_z)"
SEX = "(ex_x + ex_y + ex_z)"
SEY = "(ey_x + ey_y + ey_z)"
SEZ = "(ez_x + ez_y + ez_z)"

PRINTED: dict[str, tuple[str, str, str]] = {
    "MB1": (
        f"{SDX} + z*(-beta1 + ey_x + ey_y) - Yp*{SEZ} + Zp*{SEY}",
        f"{SDY} + x*(-alpha + ez_y) - z*(beta2 + ex_y + ex_x) + Xp*{SEZ} - Zp*{SEX}",
        f"{SDZ} - x*ey_y - Xp*{SEY} + Yp*{SEX}",
    ),
    "MB2": (
        f"{SDX} + z*(-beta1 + ey_x + ey_y) - y*ez_x - Yp*{SEZ} + Zp*{SEY}",
        f"{SDY} - x*alpha + z*(-beta2 - ex_y - ex_x) + Xp*{SEZ} - Zp*{SEX}",
        f"{SDZ} + y*ex_x - Xp*{SEY} + Yp*{SEX}",
    ),
    "FB1": (
        f"{SDX} + y*ez_y + z*(-beta1 + ey_x - ey_y) + Yp*(-ez_x + ez_y - ez_z)"
        " + Zp*(ey_x - ey_y + ey_z)",
        f"{SDY} + x*(-alpha - ez_y) + z*(-beta2 - ex_x + ex_y) + Xp*(ez_x - ez_y + ez_z)"
        " + Zp*(-ex_x + ex_y - ex_z)",
        f"{SDZ} + x*ey_y - y*ex_y + Xp*(-ey_x + ey_y - ey_z) + Yp*(ex_x - ex_y + ex_z)",
    ),
    "FB2": (
        f"{SDX} + z*(-beta1 - ey_x + ey_y) + y*ez_x + Yp*(ez_x - ez_y - ez_z)"
        " + Zp*(-ey_x + ey_y + ey_z)",
        f"{SDY} + x*(-alpha - ez_x) + z*(-beta2 + ex_x - ex_y) + Xp*(-ez_x + ez_y + ez_z)"
        " + Zp*(ex_x - ex_y - ex_z)",
        f"{SDZ} + x*ey_x - y*ex_x + Xp*(ey_x - ey_y - ey_z) + Yp*(-ex_x + ex_y + ex_z)",
    ),
    "MH1": (
        f"{SDX} + z*(-beta1 + ey_y) + phi1*x*z + Yp*(-ez_x - ez_y - ez_z) + Zp*{SEY}",
        f"{SDY} + x*(-alpha + ez_y + ez_z) + z*(-beta2 - ex_y) + Xp*{SEZ} - Zp*{SEX}",
        f"{SDZ} - x*(ey_y + ey_z) - phi2*x*x/2 - Xp*{SEY} + Yp*{SEX}",
    ),
    "MH2": (
        f"{SDX} - y*(ez_z + ez_x) + z*(-beta1 + ey_x) + Yp*(-ez_x - ez_y - ez_z) + Zp*{SEY}",
        f"{SDY} - x*alpha + z*(-beta2 - ex_x) + phi1*y*z + Xp*{SEZ} + Zp*(-ex_x - ex_y - ex_z)",
        f"{SDZ} + y*(ex_x + ex_z) + phi2*y*y/2 + Xp*(-ey_x - ey_y - ey_z) + Yp*{SEX}",
    ),
    "FH1": (
        f"{SDX} + z*(ey_y - ey_x - beta1) + Yp*(ez_x - ez_y - ez_z) + Zp*(-ey_x + ey_y + ey_z)",
        f"{SDY} + x*(-alpha - ez_x) + z*(-ex_y + ex_x - beta2) + Xp*(-ez_x + ez_y + ez_z)"
        " + Zp*(ex_x - ex_y - ex_z)",
        f"{SDZ} + x*ey_x - y*ex_x + Xp*(ey_x - ey_y - ey_z) + Yp*(-ex_x + ex_y + ex_z)",
    ),
    "FH2": (
        f"{SDX} + z*(-beta1 + ey_x - ey_y) + y*ez_y + Yp*(-ez_x + ez_y - ez_z)"
        " + Zp*(ey_x - ey_y + ey_z)",
        f"{SDY} + x*(-alpha - ez_y) + z*(-beta2 - ex_x + ex_y) + Xp*(ez_x - ez_y + ez_z)"
        " + Zp*(-ex_x + ex_y - ex_z)",
        f"{SDZ} + x*ey_y - y*ex_y + Xp*(-ey_x + ey_y - ey_z) + Yp*(ex_x - ex_y + ex_z)",
    ),
    "CX1": (
        f"{SDX} + z*(-beta1 - ey_x - ey_y) + y*ez_y + Yp*(ez_x + ez_y - ez_z)"
        " + Zp*(-ey_x - ey_y + ey_z)",
        f"{SDY} + z*(-beta2 + ex_x + ex_y) + x*(-alpha - ez_x - ez_y) + Xp*(-ez_x - ez_y + ez_z)"
        " + Zp*(ex_x + ex_y - ex_z)",
        f"{SDZ} + x*(ey_x + ey_y) - y*ex_y + Xp*(ey_x + ey_y - ey_z) + Yp*(-ex_x - ex_y + ex_z)",
    ),
    "CY1": (
        f"{SDX} + y*(ez_x + ez_y) + z*(-beta1 - ey_x - ey_y) + Yp*(ez_x + ez_y - ez_z)"
        " + Zp*(-ey_x - ey_y + ey_z)",
        f"{SDY} + z*(-beta2 + ex_y + ex_x) + x*(-alpha - ez_x) + Xp*(-ez_x - ez_y + ez_z)"
        " + Zp*(ex_x + ex_y - ex_z)",
        f"{SDZ} + x*ey_x + y*(-ex_x - ex_y) + Xp*(ey_x + ey_y - ey_z) + Yp*(-ex_x - ex_y + ex_z)",
    ),
}

#: (model, output component, term the chain requires that the printed equation lacks or differs by)
#: Each is an expression to ADD to the printed equation to obtain the chain's first-order form.
CORRECTIONS: dict[tuple[str, int], str] = {
    ("FH1", 0): "y*ez_x",  # ΔX of FH1 drops the Abbe term of the table's yaw (present in FB2)
}
