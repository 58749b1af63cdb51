"""Reasons why an object's figures may be unreliable, for the result's quality notes."""

from __future__ import annotations

from workers.pipeline.model import ObjectMeasurement, QualityNote


def object_quality_notes(
    objects: list[ObjectMeasurement], *, fps: float, band: tuple[float, float], bin_hz: float
) -> list[QualityNote]:
    """Reasons why an object's figures may be unreliable."""
    notes: list[QualityNote] = []
    for obj in objects:
        f = obj.eigenfrequency_hz
        name = f"object {obj.id} ({f:.4g} Hz)"
        if f >= 0.4 * fps:
            notes.append(
                QualityNote(
                    "possibly_aliased",
                    f"{name} is near the Nyquist rate ({fps / 2:g} Hz): the true frequency may be "
                    f"{fps - f:.4g} Hz or higher; record at a higher frame rate or give the true fps",
                )
            )
        if obj.snr_db is not None and obj.snr_db < 6:
            notes.append(
                QualityNote(
                    "low_snr",
                    f"{name}: the ring-down stands only {obj.snr_db:.1f} dB above the noise; "
                    "push harder, light the object better or film closer",
                )
            )
        periods = f * obj.fitted_duration_s
        if periods < 3:
            notes.append(
                QualityNote(
                    "few_periods",
                    f"{name}: only {periods:.1f} periods of motion were analysed; record longer after the "
                    "release for reliable frequency and damping",
                )
            )
        if f - band[0] < 1.5 * bin_hz or band[1] - f < 1.5 * bin_hz:
            notes.append(
                QualityNote(
                    "band_edge",
                    f"{name} lies at the edge of the analysed band [{band[0]:.3g}, {band[1]:.3g}] Hz; "
                    "widen the band or change the window length",
                )
            )
        if obj.saturated_fraction > 0.05:
            notes.append(
                QualityNote(
                    "saturation",
                    f"{name}: {obj.saturated_fraction * 100:.0f} % of its pixels are clipped (black or "
                    "white); reduce the exposure so its texture can be tracked",
                )
            )
    return notes


__all__ = ["object_quality_notes"]
