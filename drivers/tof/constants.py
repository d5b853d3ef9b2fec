"""SR4000 facts the driver and the simulator share: USB ids, frequencies, mode flags, units.

Numbers follow MESA's libMesaSR headers (``definesSR.h``/``libMesaSR.h``) so that a value read
from a real camera and one produced by the simulator mean the same thing.
"""

from __future__ import annotations

import enum

SPEED_OF_LIGHT = 299_792_458.0  # m/s

# USB identification (MESA Imaging). 0x0074 and 0x0075 are both SR4000 product ids.
SR4000_VENDOR_ID = 0x1AD2
SR4000_PRODUCT_IDS = (0x0074, 0x0075)

# Sensor geometry: 176 x 144 pixels, 43.6 x 34.6 degrees field of view.
WIDTH = 176
HEIGHT = 144
FOV_H_DEG = 43.6
FOV_V_DEG = 34.6

# Farthest distance whose returns are trusted: 30 MHz wraps at c/2f = 5 m, and the returns thin
# out and get noisier toward it (phase-wrapped far surfaces fold back in front).
USABLE_RANGE = 4.5  # m

# Integration time register: SR4000 time = 0.3 ms + 0.1 ms * register (libMesaSR docs).
INTEGRATION_MIN = 0
INTEGRATION_MAX = 255
INTEGRATION_BASE_MS = 0.3
INTEGRATION_STEP_MS = 0.1

# A frame is four phase samples, each exposed for the integration time, then read out.
PHASE_SAMPLES = 4
FRAME_READOUT_MS = 5.0

# Raw image codes: distance 0..0xFFFF spans the unambiguous range, confidence 0xFFFF is best.
RAW_MAX = 0xFFFF


class ModulationFrq(enum.IntEnum):
    """libMesaSR's ``enum ModulationFrq`` values: what SR_SetModulationFrequency takes."""

    MF_40MHz = 0
    MF_30MHz = 1
    MF_21MHz = 2
    MF_20MHz = 3
    MF_19MHz = 4
    MF_60MHz = 5
    MF_15MHz = 6
    MF_10MHz = 7
    MF_29MHz = 8
    MF_31MHz = 9
    MF_14_5MHz = 10
    MF_15_5MHz = 11


# The frequencies an SR4000 accepts, MHz -> libMesaSR enum. 29/31 and 14.5/15.5 exist so that
# several cameras can run side by side without interfering; the camera is calibrated at 30 MHz.
SR4000_FREQUENCIES: dict[float, ModulationFrq] = {
    29.0: ModulationFrq.MF_29MHz,
    30.0: ModulationFrq.MF_30MHz,
    31.0: ModulationFrq.MF_31MHz,
    14.5: ModulationFrq.MF_14_5MHz,
    15.0: ModulationFrq.MF_15MHz,
    15.5: ModulationFrq.MF_15_5MHz,
}

# The maximum distances MESA quotes per frequency (rounded c/2f); used to choose a frequency from
# a requested distance so that "5 m" selects 30 MHz although c/(2*30 MHz) is 4.9965 m.
NOMINAL_RANGE_M: dict[float, float] = {
    29.0: 5.17,
    30.0: 5.0,
    31.0: 4.84,
    14.5: 10.34,
    15.0: 10.0,
    15.5: 9.68,
}

# Order of preference when choosing by distance: the standard 30/15 MHz first, then the
# slightly lower variants that reach a little further. 31 and 15.5 MHz only shorten the range.
_DISTANCE_PREFERENCE = (30.0, 29.0, 15.0, 14.5)


class AcquireMode(enum.IntFlag):
    """libMesaSR's ``enum AcquireMode`` bits, OR-ed together and passed to SR_SetMode."""

    AM_COR_FIX_PTRN = 0x0001
    AM_MEDIAN = 0x0004
    AM_TOGGLE_FRQ = 0x0008
    AM_CONV_GRAY = 0x0010
    AM_SW_ANF = 0x0020
    AM_SHORT_RANGE = 0x0080  # "enhanced XYZ": precise coordinate transform below 1 m
    AM_CONF_MAP = 0x0100
    AM_HW_TRIGGER = 0x0200
    AM_SW_TRIGGER = 0x0400
    AM_DENOISE_ANF = 0x0800
    AM_MEDIANCROSS = 0x1000
    AM_NO_AMB = 0x2000


# rvs-libtof's SetImgCorrectModes takes a structure of booleans; these are its members.
CORRECTION_FLAGS: dict[str, AcquireMode] = {
    "fix_pattern": AcquireMode.AM_COR_FIX_PTRN,
    "median": AcquireMode.AM_MEDIAN,
    "denoise_anf": AcquireMode.AM_DENOISE_ANF,
    "conv_gray": AcquireMode.AM_CONV_GRAY,
    "conf_map": AcquireMode.AM_CONF_MAP,
}

# MESA's recommended SR4000 mode plus the confidence map that confidence thresholds need.
DEFAULT_CORRECTIONS = ("fix_pattern", "denoise_anf", "conv_gray", "conf_map")

# Image list order of SR_GetImageList for an SR4000 (ImgEntry::ImgType values).
IT_DISTANCE = 0
IT_AMPLITUDE = 1
IT_CONF_MAP = 8

IMAGE_TYPES = ("distance", "amplitude", "confidence", "z", "xyz")

# The second frequency of a two-frequency wrap check (Droeschel, Holz, Behnke 2010, multi-frequency
# phase unwrapping with an SR4000): half the modulation frequency, twice the unambiguous range.
# A surface beyond c/2f reads r - c/2f at the high frequency and r at the low one; a true return
# reads the same at both. The low frequencies have no partner (their 10 m already covers a room).
WRAP_CHECK_FREQUENCY: dict[float, float] = {30.0: 15.0, 29.0: 14.5, 31.0: 15.5}


def unambiguous_range(frequency_mhz: float) -> float:
    """Distance at which the phase wraps: c / (2 f)."""
    return SPEED_OF_LIGHT / (2.0 * frequency_mhz * 1e6)


def check_frequency(frequency_mhz: float) -> float:
    """Return the frequency as the table's key; ValueError names the accepted ones."""
    for f in SR4000_FREQUENCIES:
        if abs(float(frequency_mhz) - f) < 1e-6:
            return f
    accepted = ", ".join(f"{f:g}" for f in SR4000_FREQUENCIES)
    raise ValueError(f"modulation frequency {frequency_mhz} MHz is not an SR4000 frequency ({accepted} MHz)")


def frequency_for_distance(max_distance_m: float) -> float:
    """The modulation frequency to measure up to ``max_distance_m`` without ambiguity.

    Prefers the calibrated 30 MHz, then 29, 15 and 14.5 MHz: the highest frequency whose nominal
    range covers the distance, since a higher frequency gives less noise.
    """
    if not max_distance_m > 0:
        raise ValueError(f"maximum distance must be positive, got {max_distance_m}")
    for f in _DISTANCE_PREFERENCE:
        if max_distance_m <= NOMINAL_RANGE_M[f] + 1e-9:
            return f
    longest = max(NOMINAL_RANGE_M.values())
    raise ValueError(f"maximum distance {max_distance_m} m is beyond the SR4000's longest range ({longest} m at 14.5 MHz)")


def integration_ms(register: int) -> float:
    """Integration time in ms for an SR4000 register value."""
    register = check_integration(register)
    return INTEGRATION_BASE_MS + INTEGRATION_STEP_MS * register


def integration_register(ms: float) -> int:
    """Nearest register value for an integration time in ms (0.3 .. 25.8 ms)."""
    lo = INTEGRATION_BASE_MS
    hi = INTEGRATION_BASE_MS + INTEGRATION_STEP_MS * INTEGRATION_MAX
    if not lo - 1e-9 <= ms <= hi + 1e-9:
        raise ValueError(f"integration time {ms} ms outside {lo:.1f} .. {hi:.1f} ms")
    return int(round((ms - INTEGRATION_BASE_MS) / INTEGRATION_STEP_MS))


def frame_seconds(integration_ms_: float) -> float:
    """One frame's time: four phase samples of the integration time, then the read-out."""
    return (PHASE_SAMPLES * integration_ms_ + FRAME_READOUT_MS) / 1000.0


def check_integration(register: int) -> int:
    if isinstance(register, bool) or int(register) != register:
        raise ValueError(f"integration register must be an integer 0..255, got {register!r}")
    register = int(register)
    if not INTEGRATION_MIN <= register <= INTEGRATION_MAX:
        raise ValueError(f"integration register {register} outside 0..255 (0.3 ms + 0.1 ms per step)")
    return register


def modes_from_corrections(corrections: dict[str, bool], enhanced_xyz: bool, base: int = 0) -> int:
    """OR the correction booleans into an AcquireMode value, keeping unrelated bits of ``base``."""
    mode = int(base)
    for name, flag in CORRECTION_FLAGS.items():
        if name in corrections:
            mode = mode | int(flag) if corrections[name] else mode & ~int(flag)
    mode = mode | int(AcquireMode.AM_SHORT_RANGE) if enhanced_xyz else mode & ~int(AcquireMode.AM_SHORT_RANGE)
    return mode


def corrections_from_mode(mode: int) -> dict[str, bool]:
    return {name: bool(int(mode) & int(flag)) for name, flag in CORRECTION_FLAGS.items()}


def trigger_mode_name(mode: int) -> str:
    if int(mode) & AcquireMode.AM_HW_TRIGGER:
        return "hardware"
    if int(mode) & AcquireMode.AM_SW_TRIGGER:
        return "software"
    return "continuous"
