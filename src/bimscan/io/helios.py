"""HELIOS++ inputs beside the OBJ export: a scene of the component files and a survey of the scan.

Scene (``helios/scene.xml``): HELIOS++ builds a scene from ``<part>`` elements, each loading
one geometry file through a ``<filter type="objloader">`` with a ``filepath`` parameter; it
ignores OBJ groups, so every component is its own part and its own file. The part ``id`` is the
bimscan component id, which HELIOS++ reports per point as the hit object id, and
``classes.mtl`` carries ``helios_classification`` so HELIOS++'s classification matches the
bimscan label. ``up`` is ``z`` because bimscan meshes are Z-up.

Survey (``helios/survey.xml``, ``helios_survey_xml``): the same survey as ``bimscan scan``
with the same stations and settings: HELIOS++'s static ``tripod`` platform and its definition
of the scanner (``HELIOS_SCANNERS``: the RIEGL VZ-400 of ``scanners_tls.xml``), one ``<leg>``
per station. Where the pieces go, from HELIOS++'s source (``Platform::setPosition``,
``ScanningDevice::doSimStep``, ``ScannerHead``, ``PolygonMirrorBeamDeflector``):

- beam origin = leg position + the tripod's ``scannerMount`` (z 1.5 m) + the scanner's
  ``beamOrigin`` (z 0.2 m), neither turned by the head; bimscan's ``Station.position`` is the
  beam origin, so a leg stands at ``position - (0, 0, 1.7 m)`` with ``onGround="false"``
  (HELIOS++ shifts legs with its scene, so world coordinates are right as they are);
- the beam leaves along +Y at head angle 0, the mirror turns it up about +X by the elevation and
  the head turns counter-clockwise about +Z: HELIOS++'s azimuth is head angle + 90 degrees, so
  ``headRotateStart_deg = head_start_deg + heading_deg - 90`` (and the same for the stop);
- ``pulseFreq_hz`` (an integer in HELIOS++), ``scanFreq_hz`` (lines per second over the 240
  degree mirror sweep, as bimscan's), ``headRotatePerSec_deg``, ``verticalAngleMin_deg`` /
  ``verticalAngleMax_deg`` = bimscan's elevation window, and ``scanAngle_deg`` wide enough
  for it (HELIOS++ emits only where |mirror angle| <= scanAngle_deg).

Known differences a user will see (``helios_near_limit_m``): HELIOS++ computes a full waveform
per pulse and drops a pulse whose nearest hit is closer than its ``rangeMin_m`` plus the light
travel during the rise of its modelled pulse to its peak (1.5 ns of the VZ-400's 5 ns pulse:
0.45 m), so it records nothing closer than 1.95 m where bimscan records from ``min_range_m`` =
1.5 m; in a 2.6 m room with the beam at 1.7 m that removes the ceiling above about 27 degrees of
elevation. Set ``min_range_m = 1.95`` in a copy of ``scan/scanners/riegl_vz400.toml``
(``--scanner FILE``; keep its name) to match. HELIOS++'s VZ-400 also emits only where
|mirror angle| <= its ``scanAngleEffectiveMax_deg`` (50 degrees), so elevations above 50
degrees are not scanned there.

File paths in both files are relative to the export folder (``components/c12.obj``,
``helios/scene.xml``). HELIOS++ resolves the scene's paths only through its asset folders and a
mobile survey's trajectory file only from the current folder, so run it from inside the export
folder: ``cd OUT_DIR && helios++ helios/survey.xml --assets .``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

from bimscan import __version__
from bimscan.errors import ConfigError
from bimscan.types import Station

if TYPE_CHECKING:  # the scanner stage's data types, for annotations only
    from bimscan.scan.device import ScannerModel, ScanSettings
    from bimscan.scan.risley import RisleyScanner
    from bimscan.survey.mobile import MobileScan
    from bimscan.survey.trajectory import Trajectory

HELIOS_DIR = "helios"
SCENE_FILE = "helios/scene.xml"  # relative to the export folder (HELIOS++'s --assets)
SURVEY_FILE = "helios/survey.xml"
TRIPOD_ASSET = "data/platforms.xml#tripod"
TRIPOD_MOUNT_Z_M = 1.5  # <scannerMount z> of HELIOS++'s tripod platform
HEAD_ZERO_AZIMUTH_DEG = 90.0  # HELIOS++'s beam leaves along +Y at head angle 0
SPEED_OF_LIGHT_M_PER_NS = 0.299792458
FULL_WAVE_BIN_NS = 0.25  # HELIOS++'s default FWFSettings binSize_ns


@dataclass(frozen=True)
class HeliosScanner:
    """A scanner definition that HELIOS++ ships, with the figures the survey depends on.

    asset: the survey's ``scanner`` reference; beam_origin_z_m: its ``beamOrigin`` above the
    mount; mirror_sweep_deg: twice its ``scanAngleMax_deg``; scan_angle_effective_max_deg: the
    widest mirror angle it emits at; range_min_m and pulse_length_ns: its ``rangeMin_m`` and
    ``pulseLength_ns``.
    """

    asset: str
    beam_origin_z_m: float
    mirror_sweep_deg: float
    scan_angle_effective_max_deg: float
    range_min_m: float
    pulse_length_ns: float


# bimscan scanner name -> HELIOS++'s definition of the same device (data/scanners_tls.xml)
HELIOS_SCANNERS: dict[str, HeliosScanner] = {
    "riegl_vz400": HeliosScanner(asset="data/scanners_tls.xml#riegl_vz400", beam_origin_z_m=0.2,
                                 mirror_sweep_deg=240.0, scan_angle_effective_max_deg=50.0, range_min_m=1.5,
                                 pulse_length_ns=5.0),
}


def helios_near_limit_m(scanner: HeliosScanner, *, bin_ns: float = FULL_WAVE_BIN_NS) -> float:
    """The shortest range HELIOS++ records with ``scanner``, metres.

    HELIOS++ models the emitted pulse as p(t) = (t/tau)^2 exp(-t/tau), tau = pulse length / 7,
    sampled in ``bin_ns`` bins, and skips a pulse whose nearest hit is closer than rangeMin_m +
    c * t_peak (``ScanningDevice::initializeFullWaveform``, ``calcTimePropagation``).
    """
    tau = scanner.pulse_length_ns / 7.0
    bins = int(scanner.pulse_length_ns / bin_ns)
    peak = max(range(bins), key=lambda i: (i * bin_ns / tau) ** 2 * math.exp(-i * bin_ns / tau))
    return scanner.range_min_m + SPEED_OF_LIGHT_M_PER_NS * peak * bin_ns


def helios_scene_id(source: str) -> str:
    """The HELIOS++ scene id of a model file: its stem with only letters, digits, ``_`` and ``-``."""
    stem = Path(source).stem or "scene"
    return "".join(ch if ch.isalnum() or ch in "_-" else "_" for ch in stem)


def helios_scene_xml(parts: Sequence[tuple[int, str]], *, scene_id: str, name: str) -> bytes:
    """The scene XML document (UTF-8 bytes) with one objloader part per (part id, OBJ path)."""
    # Formatted directly: ElementTree takes most of a second to serialise 20k parts.
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<document>",
        f"    <scene id={quoteattr(scene_id)} name={quoteattr(name)}>",
    ]
    for part_id, filepath in parts:
        lines += [
            f'        <part id="{int(part_id)}">',
            '            <filter type="objloader">',
            f'                <param type="string" key="filepath" value={quoteattr(filepath)} />',
            '                <param type="string" key="up" value="z" />',
            "            </filter>",
            "        </part>",
        ]
    lines += ["    </scene>", "</document>"]
    return ("\n".join(lines) + "\n").encode("utf-8")


def write_helios_scene(path: Path, *, parts: Sequence[tuple[int, str]], scene_id: str, name: str) -> None:
    """Write ``helios_scene_xml(parts, ...)`` to ``path`` (the caller makes it atomic)."""
    path.write_bytes(helios_scene_xml(parts, scene_id=scene_id, name=name))


def _number(value: float) -> str:
    """A float as XML attribute text: the shortest repr that reads back exactly."""
    value = float(value)
    return "0" if value == 0 else repr(value)


def _comment(text: str) -> str:
    """``text`` as an XML comment (``--`` may not appear inside one)."""
    while "--" in text:
        text = text.replace("--", "- -")
    return f"<!-- {text.rstrip('-')} -->"


def helios_scanner(scanner: ScannerModel) -> HeliosScanner:
    """HELIOS++'s definition of a bimscan scanner model, or a ConfigError naming the ones known."""
    helios = HELIOS_SCANNERS.get(scanner.name)
    if helios is None:
        raise ConfigError(
            f"HELIOS++ survey: bimscan knows HELIOS++'s definition of {', '.join(HELIOS_SCANNERS)} only, not of "
            f"scanner {scanner.name!r}; use --scanner riegl_vz400 (or a scanner file that keeps that name)")
    if not math.isclose(scanner.mirror_sweep_deg, helios.mirror_sweep_deg):
        raise ConfigError(
            f"HELIOS++ survey: scanner {scanner.name!r} sweeps {scanner.mirror_sweep_deg:g} degrees per mirror line, "
            f"HELIOS++'s definition {helios.mirror_sweep_deg:g}; keep mirror_sweep_deg = {helios.mirror_sweep_deg:g} "
            "for a survey that matches")
    return helios


def helios_survey_xml(stations: Sequence[Station], settings: ScanSettings, scanner: ScannerModel, *,
                      scene_file: str = SCENE_FILE, scene_id: str, name: str) -> bytes:
    """The HELIOS++ survey (UTF-8 XML bytes) of a bimscan survey: one leg per station.

    ``stations``: bimscan stations (beam origins, world metres; headings in degrees);
    ``settings``/``scanner``: the scan settings and scanner model ``bimscan scan`` uses;
    ``scene_file``/``scene_id``: the scene XML (relative to HELIOS++'s asset folder) and its id.
    See the module docstring for how each value is placed. ConfigError for a scanner HELIOS++
    has no definition of, or settings it cannot take (a fractional pulse rate).
    """
    helios = helios_scanner(scanner)
    if not stations:
        raise ConfigError("HELIOS++ survey: no station; give at least one (--stations)")
    if settings.pulse_freq_hz != round(settings.pulse_freq_hz):
        raise ConfigError(f"HELIOS++ survey: pulse_freq_hz = {settings.pulse_freq_hz:g}, but HELIOS++ reads an "
                          "integer pulse rate; use a whole number of pulses per second")
    low, high = settings.window(scanner)
    beam_above_leg = TRIPOD_MOUNT_Z_M + helios.beam_origin_z_m
    near = helios_near_limit_m(helios)
    common = {
        "active": "true",
        "pulseFreq_hz": str(int(round(settings.pulse_freq_hz))),
        "scanFreq_hz": _number(settings.scan_freq_hz),
        "scanAngle_deg": _number(max(abs(low), abs(high))),
        "verticalAngleMin_deg": _number(low),
        "verticalAngleMax_deg": _number(high),
        "headRotatePerSec_deg": _number(settings.head_deg_per_s),
    }
    survey = {"name": name, "scene": f"{scene_file}#{scene_id}", "platform": TRIPOD_ASSET, "scanner": helios.asset}
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<document>",
        "    " + _comment(f"bimscan {__version__}: the survey of bimscan scan with scanner {scanner.name}, "
                          f"{len(stations)} stations. Run HELIOS++ on this file from inside the export folder "
                          "with it as its asset folder (--assets .): it finds the scene and the component files "
                          "only there."),
        "    " + _comment(f"Beam origin = leg + tripod mount {TRIPOD_MOUNT_Z_M:g} m + scanner beam origin "
                          f"{helios.beam_origin_z_m:g} m: each leg stands {beam_above_leg:g} m below the bimscan "
                          f"station. HELIOS++ head angle 0 = azimuth {HEAD_ZERO_AZIMUTH_DEG:g} deg."),
        "    " + _comment(f"HELIOS++ records nothing closer than {near:.2f} m with this scanner (bimscan: "
                          f"min_range_m = {scanner.min_range_m:g} m) and emits no elevation above "
                          f"{helios.scan_angle_effective_max_deg:g} deg (bimscan: {high:g} deg)."),
        "    <survey " + " ".join(f"{k}={quoteattr(v)}" for k, v in survey.items()) + ">",
    ]
    for station in stations:
        x, y, z = (float(v) for v in station.position)
        where = ", ".join(part for part in (f"room {station.room}" if station.room else "",
                                            f"storey {station.storey}" if station.storey else "") if part)
        leg = {"x": _number(x), "y": _number(y), "z": _number(z - beam_above_leg), "onGround": "false"}
        head = {
            **common,
            "headRotateStart_deg": _number(settings.head_start_deg + station.heading_deg - HEAD_ZERO_AZIMUTH_DEG),
            "headRotateStop_deg": _number(settings.head_stop_deg + station.heading_deg - HEAD_ZERO_AZIMUTH_DEG),
        }
        lines += [
            "        " + _comment(f"bimscan station {station.id}" + (f" ({where})" if where else "")
                                  + f": beam origin {_number(x)} {_number(y)} {_number(z)} m, "
                                  f"heading {_number(station.heading_deg)} deg"),
            "        <leg>",
            "            <platformSettings " + " ".join(f"{k}={quoteattr(v)}" for k, v in leg.items()) + " />",
            "            <scannerSettings " + " ".join(f"{k}={quoteattr(v)}" for k, v in head.items()) + " />",
            "        </leg>",
        ]
    lines += ["    </survey>", "</document>"]
    return ("\n".join(lines) + "\n").encode("utf-8")


# bimscan multi-beam lidar -> HELIOS++'s definition of it (data/scanners_tls.xml)
HELIOS_LIDARS: dict[str, str] = {"velodyne_vlp16": "data/scanners_tls.xml#vlp16"}
INTERPOLATED_BASE_PLATFORM = "data/platforms.xml#tripod"  # an interpolated platform needs a base; the survey's mount replaces its own
HEAD_SAMPLE_S = 0.05  # trajectory samples of a turning mount (its head turn folded into the yaw)
RISLEY_SCANNERS_FILE = "helios/scanners.xml"  # a Risley lidar's definition, written with its survey
# HELIOS++'s Risley beam leaves along its scanner's +Y, bimscan's along the sensor's +z: the sensor
# frame is HELIOS++'s turned 90 degrees about x (bimscan (x, y, z) = HELIOS++ (x, -z, y))
RISLEY_FRAME_X_DEG = 90.0
HELIOS_MAX_PRISMS = 3  # HELIOS++ reads angle1..3_deg


def helios_risley_scanner_xml(lidar: RisleyScanner) -> bytes:
    """A HELIOS++ scanner definition (``optics="risley"``) of a bimscan Risley lidar: the same prisms
    (``angleK_deg`` positive for an inclined entrance face, negative for an inclined exit face;
    ``rotorFreqK_Hz``; ``refrIndexK``), the same channels (``incidentBeam``, in HELIOS++'s frame:
    ``RISLEY_FRAME_X_DEG``), pulse rate, accuracy, divergence, minimum range and wavelength.
    HELIOS++ starts every prism with its inclined face's normal at -90 degrees (entrance) or +90
    degrees (exit) in bimscan's frame; ConfigError for a lidar whose prisms start elsewhere, with
    more than three prisms, or on a spinning head (HELIOS++'s Risley optics do not spin)."""
    prisms = lidar.prisms
    if lidar.spinning:
        raise ConfigError(f"HELIOS++'s risley optics do not spin; {lidar.name}'s head turns at {lidar.spin_hz:g} Hz: "
                          "export it with a Risley lidar without a spinning head, or with --scanner velodyne_vlp16")
    if len(prisms) > HELIOS_MAX_PRISMS:
        raise ConfigError(f"HELIOS++ models at most {HELIOS_MAX_PRISMS} prisms; {lidar.name} has {len(prisms)}")
    attributes = {"id": lidar.name, "name": lidar.description or lidar.name, "optics": "risley",
                  "accuracy_m": _number(lidar.range_accuracy_m), "beamDivergence_rad": _number(lidar.beam_divergence_rad),
                  "pulseFreqs_Hz": str(int(round(lidar.pulse_rate_hz))), "pulseLength_ns": "4",
                  "rangeMin_m": _number(lidar.min_range_m), "wavelength_nm": _number(lidar.wavelength_nm),
                  "maxNOR": "1", "refrIndex_air": "1.0"}
    for k, prism in enumerate(prisms, start=1):
        entrance = prism.inclined_face == "entrance"
        if abs(prism.start_deg - (-90.0 if entrance else 90.0)) > 1e-9:
            raise ConfigError(f"HELIOS++ starts a prism whose {prism.inclined_face} face is inclined at "
                              f"{-90 if entrance else 90} degrees; {lidar.name}'s prism {k} starts at "
                              f"{prism.start_deg:g}")
        attributes[f"rotorFreq{k}_Hz"] = _number(prism.rotation_hz)
        attributes[f"angle{k}_deg"] = _number(prism.wedge_deg if entrance else -prism.wedge_deg)
        attributes[f"refrIndex{k}"] = _number(prism.refractive_index)
    incident = lidar.incident()
    channels = "".join(f'                <channel id="{c}">\n                    <incidentBeam x="{d[0]:.9f}" '
                       f'y="{d[2]:.9f}" z="{-d[1] + 0.0:.9f}" />\n                </channel>\n'
                       for c, d in enumerate(incident))
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<document>",
             "    " + _comment(f"bimscan {__version__}: {lidar.name} as HELIOS++'s Risley optics"),
             "    <scanner " + " ".join(f"{key}={quoteattr(v)}" for key, v in attributes.items()) + ">",
             '        <beamOrigin x="0" y="0" z="0" />', "        <channels>",
             channels.rstrip("\n"), "        </channels>", "    </scanner>", "</document>"]
    return ("\n".join(lines) + "\n").encode("utf-8")


def helios_mobile_files(trajectory: Trajectory, mobile: MobileScan, *, scene_file: str = SCENE_FILE, scene_id: str,
                        name: str) -> dict[str, bytes]:
    """The HELIOS++ survey of a mobile scan, as files relative to the export folder: per lidar of
    the platform, a survey on HELIOS++'s interpolated platform (``helios/survey.xml`` for the
    first, ``helios/survey_mount<k>.xml`` for the others; HELIOS++ runs one scanner per survey)
    and the trajectory it follows (``helios/trajectory_mount<k>.trj``), one leg per pass.

    How the pieces go, from HELIOS++'s source (``XmlAssetsLoader::createInterpolatedMovingPlatform``,
    ``InterpolatedMovingPlatform``, ``XmlUtils::createRotationFromXml``, its ``vlp16`` definition):

    - trajectory columns t, roll, pitch, yaw, x, y, z (its default indices), angles in degrees
      (``toRadians="true"``), attitude ``rotationSpec="CANONICAL"``: R = Rx(roll) Ry(pitch)
      Rz(yaw), the same frame as bimscan's platform (x forward, z up); bimscan's Rz(yaw) Ry(pitch)
      Rx(roll) is converted, and a mount's head turn (about the platform's z, at the mount) is
      folded into the attitude, sampled every ``HEAD_SAMPLE_S``;
    - the survey's ``<scannerMount>``: the mount's lever arm, then its tilt about y and its yaw
      about z (global rotations, in that order: Rz(yaw) Ry(tilt), as bimscan's mount);
    - HELIOS++'s VLP-16 fires all channels at once at ``pulseFreq_hz`` and its beam leaves along
      +Y at head angle 0: one pulse per bimscan firing sequence (round(1 / cycle)), and the head
      starts at -90 degrees, turning 360 x rotation_hz degrees per second.

    ConfigError for a lidar HELIOS++ has no definition of.
    """
    import numpy as np
    from scipy.spatial.transform import Rotation

    from bimscan.scan.risley import RisleyScanner

    lidar = mobile.lidar
    risley = isinstance(lidar, RisleyScanner)
    files: dict[str, bytes] = {}
    if risley:  # written beside the survey: HELIOS++'s risley optics with bimscan's prisms
        files[RISLEY_SCANNERS_FILE] = helios_risley_scanner_xml(lidar)
        asset = f"{RISLEY_SCANNERS_FILE}#{lidar.name}"
    else:
        asset = HELIOS_LIDARS.get(lidar.name)
    if asset is None:
        raise ConfigError(f"HELIOS++ survey: bimscan knows HELIOS++'s definition of {', '.join(HELIOS_LIDARS)} only, "
                          f"not of {lidar.name!r}; export a mobile survey with --scanner velodyne_vlp16 or a Risley "
                          "lidar")
    pulse_hz = int(round(1e6 / lidar.firing_cycle_us))
    for k, mount in enumerate(mobile.platform.mounts):
        times, rows = [], []
        for part in trajectory.pass_slices():
            t = trajectory.t[part]
            grid = np.union1d(t, np.arange(t[0], t[-1], HEAD_SAMPLE_S)) if mount.head_rotation_hz else t
            yaw = np.interp(grid, t, np.unwrap(trajectory.yaw[part]))
            pitch = np.interp(grid, t, trajectory.pitch[part])
            roll = np.interp(grid, t, trajectory.roll[part])
            head = 2 * math.pi * mount.head_rotation_hz * grid
            attitude = (Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
                        * Rotation.from_euler("z", head[:, None]))
            with warnings.catch_warnings():  # a drone's gimbal straight down is pitch 90: scipy's gimbal lock
                warnings.simplefilter("ignore", UserWarning)  # (its angles still give the same attitude)
                angles = attitude.as_euler("XYZ", degrees=True)  # CANONICAL: Rx(roll) Ry(pitch) Rz(yaw)
            if risley:  # a drone's gimbal straight down leaves every angle free to jump: all unwrapped
                angles = np.degrees(np.unwrap(np.radians(angles), axis=0))
            else:
                angles[:, 2] = np.degrees(np.unwrap(np.radians(angles[:, 2])))
            xyz = np.column_stack([np.interp(grid, t, trajectory.xyz[part][:, axis]) for axis in range(3)])
            times.append((float(grid[0]), float(grid[-1])))
            rows += [f"{g:.6f},{a[0]:.6f},{a[1]:.6f},{a[2]:.6f},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}"
                     for g, a, p in zip(grid, angles, xyz)]
        track = f"{HELIOS_DIR}/trajectory_mount{k}.trj"
        files[track] = ("#TIME_COLUMN: 0\n#HEADER: \"t\", \"roll\", \"pitch\", \"yaw\", \"x\", \"y\", \"z\"\n"
                        + "\n".join(rows) + "\n").replace("-0.000000", "0.000000").encode("ascii")
        survey = {"name": f"{name}_mount{k}", "scene": f"{scene_file}#{scene_id}", "platform": "interpolated",
                  "basePlatform": INTERPOLATED_BASE_PLATFORM, "rotationSpec": "CANONICAL", "scanner": asset}
        mount_xyz = {"x": _number(mount.forward_m), "y": _number(mount.lateral_m), "z": _number(mount.height_m)}
        lines = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            "<document>",
            "    " + _comment(f"bimscan {__version__}: the mobile scan of bimscan scan with platform "
                              f"{mobile.platform.name}, {lidar.name}"
                              f"{'' if risley else f' at {mobile.rotation_hz:g} Hz'}, lidar {k + 1} of "
                              f"{len(mobile.platform.mounts)}, {trajectory.n_passes} passes (one leg each). Run HELIOS++ "
                              "on this file from inside the export folder with --assets . (it opens the trajectory "
                              "file from the current folder)."),
            "    " + _comment(f"HELIOS++ fires the {lidar.n_beams} channels at once {pulse_hz} times a second; bimscan "
                              + ("too." if risley else f"fires them one after another within each "
                                                       f"{lidar.firing_cycle_us:g} us sequence.")),
            "    <survey " + " ".join(f"{key}={quoteattr(v)}" for key, v in survey.items()) + ">",
            "        <scannerMount " + " ".join(f"{key}={quoteattr(v)}" for key, v in mount_xyz.items()) + ">",
            *([f'            <rot axis="x" angle_deg="{_number(RISLEY_FRAME_X_DEG)}" />'] if risley else []),
            f'            <rot axis="y" angle_deg="{_number(mount.tilt_deg)}" />',
            f'            <rot axis="z" angle_deg="{_number(mount.yaw_deg)}" />',
            "        </scannerMount>",
        ]
        for index, (start, stop) in enumerate(times):
            platform = {"trajectory": track, "tIndex": "0", "rollIndex": "1", "pitchIndex": "2", "yawIndex": "3",
                        "xIndex": "4", "yIndex": "5", "zIndex": "6", "toRadians": "true", "slopeFilterThreshold": "0.0",
                        "syncGPSTime": "false", "tStart": _number(start), "tEnd": _number(stop),
                        "teleportToStart": "true"}
            if index:  # the indices are given once per trajectory file
                for key in ("tIndex", "rollIndex", "pitchIndex", "yawIndex", "xIndex", "yIndex", "zIndex"):
                    del platform[key]
            if risley:  # no head: the prisms turn at the scanner file's rates
                scanner = {"active": "true", "pulseFreq_hz": str(pulse_hz), "headRotatePerSec_deg": "0",
                           "trajectoryTimeInterval_s": _number(HEAD_SAMPLE_S)}
            else:
                turn = 360.0 * mobile.rotation_hz
                scanner = {"active": "true", "pulseFreq_hz": str(pulse_hz), "scanFreq_hz": "0",
                           "headRotatePerSec_deg": _number(turn),
                           "headRotateStart_deg": _number(-HEAD_ZERO_AZIMUTH_DEG),
                           "headRotateStop_deg": _number(-HEAD_ZERO_AZIMUTH_DEG + turn * (stop - start)),
                           "trajectoryTimeInterval_s": _number(HEAD_SAMPLE_S)}
            lines += [
                "        " + _comment(f"pass {index}: t {start:.3f} to {stop:.3f} s"),
                "        <leg>",
                "            <platformSettings " + " ".join(f"{key}={quoteattr(v)}" for key, v in platform.items()) + " />",
                "            <scannerSettings " + " ".join(f"{key}={quoteattr(v)}" for key, v in scanner.items()) + " />",
                "        </leg>",
            ]
        lines += ["    </survey>", "</document>"]
        files[SURVEY_FILE if k == 0 else f"{HELIOS_DIR}/survey_mount{k}.xml"] = ("\n".join(lines) + "\n").encode("utf-8")
    return files


__all__ = [
    "HELIOS_LIDARS", "HELIOS_SCANNERS", "helios_mobile_files", "HeliosScanner", "SCENE_FILE", "SURVEY_FILE", "helios_near_limit_m", "helios_scanner",
    "helios_scene_id", "helios_scene_xml", "helios_survey_xml", "write_helios_scene",
]
