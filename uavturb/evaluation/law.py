"""The ground-effect law Table 2 scores with: the vehicle's constants identified on the first flight
(:func:`uavturb.sysid.identification.identify`; where it has no free flight to identify on, its
``vehicle.yaml`` constants, said so), ``(alpha, beta)`` of ``f = alpha sum(Omega^2) / (d^2 - beta)``
fitted by BFGS on the first flight's airborne frames with their true heights
(:func:`uavturb.physics.ground_effect.identify_alpha_beta`, as the paper does on V1_01_easy),
and its check against the vehicle (:func:`law_consistency`)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from uavturb.errors import InputError
from uavturb.evaluation.bands import ground_effect_height
from uavturb.physics.ground_effect import identify_alpha_beta
from uavturb.sysid.flight_data import FlightData
from uavturb.sysid.identification import identify


def evaluation_vehicle(first: Any, progress: bool) -> tuple[Any, str, Callable[[FlightData], FlightData] | None]:
    """(vehicle, where its constants come from, how every flight's rotor speeds are read for them): identified on
    the first flight, else (said so) its ``vehicle.yaml``'s constants. The reading is the identification's
    (:meth:`~uavturb.sysid.identification.Identification.flight_data_read`: commanded speeds moved by an idle speed
    and lagged by the motors' lag where it read and applied them, said so); None where the speeds are read as
    recorded. The ground-truth f_a and the law's sum of squared speeds need it: a thrust coefficient identified on
    moved speeds, applied to the speeds as recorded, misreads the thrust away from hover."""
    read = None
    try:
        ident = identify([first], first.vehicle)
        veh = ident.apply(first.vehicle)
        vehicle_source = f"identified on {first.name}"
        if ident.fallbacks(first.vehicle):
            vehicle_source += "; " + "; ".join(ident.fallbacks(first.vehicle))
        how = ident.speeds_read_note()
        if how:
            read = ident.flight_data_read
            vehicle_source += f"; every flight's commanded rotor speeds read as they were identified, {how}"
    except InputError as e:
        if not first.vehicle.is_complete():
            raise InputError(f"{first.path}/vehicle.yaml", f"cannot identify the vehicle ({e.problem}) and "
                                                             "its constants are incomplete") from None
        veh = first.vehicle
        vehicle_source = f"{first.name}/vehicle.yaml (identification impossible: {e.problem})"
    if progress:
        print(f"vehicle constants: {vehicle_source}", file=sys.stderr)
    return veh, vehicle_source, read


def fit_ground_effect_law(first: Any, path: Any, ge_fraction: float, progress: bool) -> tuple[Any, float]:
    """(``(alpha, beta)`` fit by BFGS on the first flight's airborne frames with their true heights,
    the ground-effect region's height [m])."""
    if not first.airborne.any():
        raise InputError(str(path), "no airborne frame (rotor thrust >= 0.3 m g) to identify (alpha, beta) on")
    air = first.airborne
    fit = identify_alpha_beta(first.fa[air], first.d[air], first.sum_omega2[air])
    h_ge = ground_effect_height(fit.beta, ge_fraction)
    if progress:
        print(f"(alpha, beta) by BFGS on {first.name}: alpha = {fit.alpha:.4g} +- {fit.stderr_alpha:.2g} "
              f"N m^2/(rad/s)^2, "
              f"beta = {fit.beta:.4g} +- {fit.stderr_beta:.2g} m^2 (fit RMSE {fit.rmse:.4f} N, {fit.n} frames); "
              f"ground-effect region d <= {h_ge:.3f} m "
              f"(law >= {100 * ge_fraction:g} % of thrust)", file=sys.stderr)
    return fit, h_ge


#: the law's own k_T (alpha / beta) may differ from the vehicle's by this factor before it is flagged
LAW_K_T_TOLERANCE = 1.25


def law_consistency(fit: Any, k_T: float) -> str | None:
    """A warning when the fitted law contradicts the vehicle: the paper's form has ``alpha = k_T beta``,
    so ``alpha / beta`` must be the thrust coefficient; ``None`` when it agrees within a factor
    :data:`LAW_K_T_TOLERANCE`. Where it does not, ``alpha`` and ``beta`` traded off against each
    other (flights at few heights) or the identified ``k_T`` took part of the law (its far tail is
    nearly a constant share of thrust), and ``mu = 16 beta / r^2`` is not to be read off."""
    ratio = fit.k_T() / k_T
    if 1 / LAW_K_T_TOLERANCE <= ratio <= LAW_K_T_TOLERANCE:
        return None
    return (f"the fitted law implies k_T = alpha / beta = {fit.k_T():.3g} N/(rad/s)^2, {ratio:.2f} times the vehicle's "
            f"{k_T:.3g}: alpha and beta are traded off "
            f"(few heights, or the identified k_T absorbed the law's far tail); "
            f"the law still scores RMSE(f_a,phi), but its beta (hence mu and the ground-effect region) is not reliable")


@dataclass(frozen=True)
class EvaluationLaw:
    """What every run of an evaluation is scored with: the flights, the vehicle identified on the
    first, the ground-effect law fitted on the first flight's true heights and its check against
    the vehicle (:func:`law_consistency`)."""

    recordings: list[Any]
    vehicle_source: str
    fit: Any
    h_ge: float
    law_check: str | None
    ge_fraction: float

    def info(self) -> dict[str, Any]:
        """The law and where it comes from, for ``evaluation.json`` and ``summary.json``."""
        f = self.fit
        return {"recordings": [str(r.path) for r in self.recordings], "alpha": f.alpha, "beta": f.beta,
                "alpha_beta_fit_rmse": f.rmse, "alpha_stderr": f.stderr_alpha, "beta_stderr": f.stderr_beta,
                "law_check": self.law_check, "identified_on": self.recordings[0].name,
                "vehicle_constants": self.vehicle_source, "ge_fraction": self.ge_fraction, "h_ge": self.h_ge}

    def params(self) -> dict[str, Any]:
        """The MLflow params of an evaluation's child run."""
        return {"alpha": self.fit.alpha, "beta": self.fit.beta, "h_ge": self.h_ge, "ge_fraction": self.ge_fraction,
                "identified_on": self.recordings[0].name,
                "recordings": ",".join(r.name for r in self.recordings), "vehicle_constants": self.vehicle_source}


def evaluation_law(recs: Sequence[Any], first: Any, vehicle: Any, vehicle_source: str, ge_fraction: float,
                   progress: bool) -> EvaluationLaw:
    """:func:`fit_ground_effect_law` on ``first`` (the first flight's sequence) and :func:`law_consistency`
    against ``vehicle``, warned on stderr when it fails."""
    fit, h_ge = fit_ground_effect_law(first, recs[0].path, ge_fraction, progress)
    law_check = law_consistency(fit, vehicle.thrust_coefficient)
    if law_check and progress:
        print(f"warning: {law_check}", file=sys.stderr)
    return EvaluationLaw(list(recs), vehicle_source, fit, h_ge, law_check, ge_fraction)
