"""The clutter library: parametric objects made in code, sized after standards and body data.

``CLUTTER_KINDS`` maps a kind name to a ``ClutterKind``: its class (``site.classes``), group
(``office``, ``ceiling``, ``site``, ``people``), how often it is drawn, whether it stands against a
wall, the size ranges its objects keep to and where they come from. Kinds of the ``ceiling`` group
(luminaires, air terminals) are mounted under the ceiling: they are not drawn by weight but laid out
in an even grid over a room (``spacing_m``), in a share of the rooms (``room_probability``). ``ClutterKind.make(rng, headroom_m,
against_wall)`` draws one object: a closed triangle mesh in its own frame (width along x, depth
along y with the back at +y, z up from the floor at 0, the footprint's box centred on the origin;
objects stand on the floor, but for boards hung on a wall; a ceiling object's top, z = its height,
goes against the ceiling) or None when it cannot stand under ``headroom_m`` (for a ceiling object:
when it would hang lower than ``MIN_CLEAR_UNDER_FIXTURE_M`` above the floor). Every dimension is drawn from a range, so
objects vary in size and proportions with the seed.

Sources of the ranges (typical products within what the standards say; the standards' own texts
were read in public summaries):

- desks: EN 527-1:2011 (office work tables; dimensions based on the 5th-95th percentile European
  user, statures 1.49-1.91 m); fixed-height desks about 0.72-0.76 m, tops 1.2-1.8 x 0.7-0.9 m.
- chairs: EN 1335-1:2020 (office work chairs; seat height at least 0.40 m, adjustable over at
  least 0.12 m; seat depth 0.38-0.47 m); five-star bases 0.6-0.7 m across.
- sofas: Neufert, *Architects' Data* (seating): seats 0.40-0.45 m high, 1.5-2.2 m wide (two or
  three seats), 0.8-0.95 m deep, backs 0.75-0.9 m high.
- shelves and cabinets: office storage in folder heights (1 OH = 0.375 m, 2-6 OH), widths
  0.8-1.2 m, depths 0.3-0.47 m (shelves) and 0.45-0.7 m (pedestals, filing cabinets).
- whiteboards: mobile boards 1.2-1.8 x 0.9-1.2 m on stands, bottom edge at 0.75-0.9 m; wall boards
  1.2-2.4 x 0.9-1.2 m hung with the bottom edge at 0.85-1.0 m.
- pallets: EN 13698-1 (EUR pallet 1.20 x 0.80 x 0.144 m); plasterboard stacks: EN 520 boards
  1.2 m wide, 2.0-3.0 m long, on bearers.
- scaffold boards on trestles: BS 2482 (boards 0.225 x 0.038 m); trestles 0.6-1.2 m high.
- buckets: builder's buckets 10-20 l (0.26-0.34 m across, 0.25-0.38 m high), mortar tubs 65-90 l.
- cable drums: wooden drums, flanges 0.5-1.0 m across (DIN 46391 drum series start here).
- waste bins: EN 840-1 two-wheeled containers, 120 l (0.48 x 0.55 x 0.93 m) to 360 l
  (0.60 x 0.88 x 1.10 m).
- ladders: EN 131-1 (rung and step spacing 0.25-0.30 m, inner width at least 0.28 m); leaning
  ladders at 75 degrees (1 out for 4 up, EN 131-3 user instructions); stepladders 3-8 steps.
- mobile scaffold towers: EN 1004-1:2020 (platforms 0.6-1.45 m wide, 1.8-2.5 m long, principal
  guardrail about 1.0 m above the platform, toe boards at least 0.15 m, castors with brakes).
- props: EN 1065 adjustable telescopic steel props (1.04 m to 5.5 m extended; outer tube about
  60 mm, inner 48 mm, end plates 150 x 150 mm).
- ceiling luminaires: laid out for EN 12464-1:2021 office lighting (500 lx on the task area) with
  office luminaires' spacing-to-height ratio of about 1.0-1.5 (CIBSE SLL *Lighting Guide 7: Offices*)
  over the 0.75 m work plane: spacing 1.8-2.7 m under 2.6-3.0 m ceilings. Panels take a ceiling
  grid module (EN 13964 suspended ceilings: 600 x 600, 625 x 625, 1200 x 300, 1250 x 312.5,
  1500 x 300, 1200 x 600 mm) and show 12 mm (a recessed troffer's trim) to 100 mm (a surface-mounted
  box) below the ceiling; linear pendants are sized for T5 lamps (IEC 60081: 1149 and 1449 mm
  tubes): 1.15-1.6 m long, 60-300 mm wide, 40-100 mm deep, on two cables 0.3-0.9 m long.
  Under a suspended ceiling most panels are lay-in troffers (``TROFFER_FRACTION`` of those rooms):
  set into the tiles, their louvre 30-120 mm above the tiles' underside (parabolic louvres are
  50-80 mm deep; the ceiling lights of the 12 shared S3DIS rooms lie 3-14 cm above their ceiling
  plane), housings 60-100 mm deep above that, the opening lined by a 5 mm trim.
  Downlights: trims 120-250 mm across, 5-30 mm proud, spacing 1.2-1.8 m.
- air terminals: square ceiling diffusers of the usual face sizes (300-625 mm, sized to the
  ceiling module), 20-60 mm of stepped cones below the ceiling; one per 10-20 m2 of office
  (spacing 3.0-4.5 m).
- nothing mounted under a ceiling hangs lower than 2.1 m above the floor (the clear height kept
  for a tripod and a person; stair and door headroom in building codes is 2.0 m).
- people: statures 1.49-1.91 m (EN 527-1's European 5th percentile female to 95th percentile
  male); body segments as fractions of stature after Drillis & Contini (1966), as tabulated in
  Winter, *Biomechanics and Motor Control of Human Movement* (4th ed., 2009), Fig. 4.1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from bimscan.errors import ConfigError
from bimscan.site.shapes import MeshBuilder

GROUPS = ("office", "ceiling", "site", "people")
MOUNTS = ("floor", "ceiling")
FOLDER_HEIGHT_M = 0.375  # one "OH": the height of a row of lever-arch files with its shelf
MIN_CLEAR_UNDER_FIXTURE_M = 2.1  # nothing under a ceiling hangs lower (see the module docs)
CABLE_M = 0.004  # a pendant's suspension cable (drawn square)
# a lay-in troffer in a suspended ceiling: its louvre above the tiles' underside (parabolic louvres
# 50-80 mm deep; the ceiling lights of the shared S3DIS rooms lie 3-14 cm above their ceiling
# plane), its housing above that, a trim lining the opening
TROFFER_RECESS_M = (0.03, 0.12)
TROFFER_HOUSING_M = (0.06, 0.1)
TROFFER_FRACTION = 0.8  # of the rooms with panel lights under a suspended ceiling: lay-in, not surface
TRIM_M = 0.005
# ceiling grid modules (EN 13964), width x depth in metres
CEILING_MODULES_M = ((0.6, 0.6), (0.625, 0.625), (1.2, 0.3), (1.25, 0.3125), (1.5, 0.3), (1.2, 0.6))


@dataclass(frozen=True)
class ClutterObject:
    """One drawn object: a closed mesh in its own frame (see the module docs).

    vertices: (V, 3) float64 metres; faces: (F, 3) int32; size_m: width (x) and depth (y) of its
    bounding box and the height of its top above the floor (z); class_name: a
    ``site.classes.SITE_CLASSES`` name.
    """

    vertices: np.ndarray
    faces: np.ndarray
    class_name: str
    size_m: tuple[float, float, float]


MakeObject = Callable[[np.random.Generator, float, bool], ClutterObject | None]


@dataclass(frozen=True)
class ClutterKind:
    """One kind of object of the library.

    weight: relative frequency among the kinds drawn together. wall_probability: how often it is
    put with its back against a wall (else free-standing). free_yaw: free-standing objects turn
    any way (else they follow the room's axes). size_ranges_m: (min, max) of the bounding box's
    width, depth and height, in metres, that every object keeps to. mount: ``floor`` (stands on the
    floor, or hangs on a wall) or ``ceiling`` (laid out in a grid of ``spacing_m``, min and max
    in metres, in ``room_probability`` of the rooms; weight, wall_probability and free_yaw unused).
    """

    name: str
    group: str
    class_names: tuple[str, ...]
    weight: float
    wall_probability: float
    free_yaw: bool
    size_ranges_m: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    make: MakeObject
    mount: str = "floor"
    spacing_m: tuple[float, float] = (0.0, 0.0)
    room_probability: float = 1.0
    lay_in: bool = False  # its panels are set into suspended ceilings (``recessed_troffer``) where they can


def _finish(builder: MeshBuilder, class_name: str, *, on_floor: bool = True) -> ClutterObject:
    """Centre the footprint's box on the origin and stand the object on z = 0 (``on_floor``; else
    it keeps its height, as a board hung on a wall)."""
    vertices, faces = builder.build()
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = vertices - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] if on_floor else 0.0])
    top = (hi[2] - lo[2]) if on_floor else hi[2]
    return ClutterObject(vertices=vertices, faces=faces, class_name=class_name,
                         size_m=(float(hi[0] - lo[0]), float(hi[1] - lo[1]), float(top)))


# ----------------------------------------------------------------------------- office furniture

def make_desk(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    width, depth, height = rng.uniform(1.2, 1.8), rng.uniform(0.7, 0.9), rng.uniform(0.72, 0.76)
    top = 0.025
    b = MeshBuilder()
    b.box((-width / 2, -depth / 2, height - top), (width / 2, depth / 2, height))
    leg_top = height - top
    if rng.random() < 0.5:  # four square legs
        for sx in (-1, 1):
            for sy in (-1, 1):
                x, y = sx * (width / 2 - 0.05), sy * (depth / 2 - 0.05)
                b.box((x - 0.025, y - 0.025, 0.0), (x + 0.025, y + 0.025, leg_top))
    else:  # panel ends and a modesty panel at the back
        for sx in (-1, 1):
            x = sx * (width / 2 - 0.03)
            b.box((x - 0.015, -depth / 2 + 0.03, 0.0), (x + 0.015, depth / 2 - 0.03, leg_top))
        b.box((-width / 2 + 0.05, depth / 2 - 0.06, leg_top - 0.35), (width / 2 - 0.05, depth / 2 - 0.04, leg_top))
    if rng.random() < 0.6 and height + 0.45 < headroom_m:  # a monitor on its stand, a keyboard
        screen_w, screen_h = rng.uniform(0.5, 0.62), rng.uniform(0.3, 0.38)
        x, y = rng.uniform(-width / 4, width / 4), depth / 2 - 0.2
        b.box((x - 0.1, y - 0.08, height), (x + 0.1, y + 0.08, height + 0.01))
        b.box((x - 0.02, y - 0.015, height + 0.01), (x + 0.02, y + 0.015, height + 0.12))
        b.box((x - screen_w / 2, y - 0.04, height + 0.08), (x + screen_w / 2, y - 0.015, height + 0.08 + screen_h))
        b.box((x - 0.22, -depth / 2 + 0.12, height), (x + 0.22, -depth / 2 + 0.27, height + 0.03))
    for _ in range(int(rng.integers(0, 3))):  # files and paper stacks (A4: 0.21 x 0.30 m)
        x, y = rng.uniform(-width / 2 + 0.2, width / 2 - 0.2), rng.uniform(-depth / 2 + 0.2, depth / 2 - 0.2)
        if abs(x) > width / 4 + 0.3:
            b.box((x - 0.15, y - 0.105, height), (x + 0.15, y + 0.105, height + rng.uniform(0.01, 0.08)))
    return _finish(b, "Clutter.Desk")


def make_chair(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    seat_h, seat_w, seat_d = rng.uniform(0.40, 0.52), rng.uniform(0.44, 0.52), rng.uniform(0.40, 0.47)
    back_h, radius = rng.uniform(0.40, 0.60), rng.uniform(0.30, 0.35)
    b = MeshBuilder()
    b.box((-seat_w / 2, -seat_d / 2, seat_h - 0.07), (seat_w / 2, seat_d / 2, seat_h))
    back_w = seat_w - 0.04
    b.box((-back_w / 2, seat_d / 2 - 0.05, seat_h + 0.05), (back_w / 2, seat_d / 2, seat_h + back_h))
    b.box((-0.03, seat_d / 2 - 0.04, seat_h - 0.05), (0.03, seat_d / 2 - 0.01, seat_h + 0.06))  # back support
    b.prism((0.0, 0.0, 0.10), (0.0, 0.0, seat_h - 0.07), 0.025, sides=10)  # gas column
    for k in range(5):  # five-star base on castors
        angle = math.pi / 2 + k * 2 * math.pi / 5
        end = (radius * math.cos(angle), radius * math.sin(angle))
        b.member((0.0, 0.0, 0.08), (end[0], end[1], 0.08), 0.05, 0.04)
        b.prism((end[0], end[1], 0.0), (end[0], end[1], 0.06), 0.025, sides=8)
    if rng.random() < 0.5:  # armrests
        for sx in (-1, 1):
            x = sx * (seat_w / 2 + 0.02)
            b.box((x - 0.015, -0.02, seat_h - 0.06), (x + 0.015, 0.02, seat_h + 0.19))
            b.box((x - 0.03, -0.15, seat_h + 0.19), (x + 0.03, 0.10, seat_h + 0.22))
    return _finish(b, "Clutter.Chair")


def make_sofa(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    width, depth, back = rng.uniform(1.5, 2.2), rng.uniform(0.8, 0.95), rng.uniform(0.75, 0.9)
    seat, arm = rng.uniform(0.40, 0.45), rng.uniform(0.1, 0.2)
    b = MeshBuilder()
    b.box((-width / 2, -depth / 2, 0.05), (width / 2, depth / 2, seat - 0.12))  # base
    cushions = 2 if width < 1.8 else 3
    step = (width - 2 * arm) / cushions
    for k in range(cushions):  # seat cushions with a small gap between them
        x = -width / 2 + arm + k * step
        b.box((x + 0.005, -depth / 2, seat - 0.12), (x + step - 0.005, depth / 2 - 0.2, seat))
    b.box((-width / 2 + arm, depth / 2 - 0.2, seat - 0.12), (width / 2 - arm, depth / 2, back))  # back
    for sx in (-1, 1):
        x = sx * (width / 2 - arm / 2)
        b.box((x - arm / 2, -depth / 2, 0.05), (x + arm / 2, depth / 2, seat + 0.2))  # arms
        for sy in (-1, 1):
            b.box((x - 0.03, sy * (depth / 2 - 0.06) - 0.03, 0.0), (x + 0.03, sy * (depth / 2 - 0.06) + 0.03, 0.05))
    return _finish(b, "Clutter.Sofa")


def _files(b: MeshBuilder, rng: np.random.Generator, x0: float, x1: float, y0: float, y1: float, z: float,
           height: float) -> None:
    """Rows of files and books standing on a shelf from x0 to x1 (some gaps)."""
    x = x0
    while x < x1 - 0.1:
        length = min(rng.uniform(0.1, 0.5), x1 - x)
        if rng.random() < 0.7 and length > 0.05:
            b.box((x, y0, z), (x + length, rng.uniform(y0 + 0.18, y1), z + rng.uniform(0.6, 0.95) * height))
        x += length + rng.uniform(0.0, 0.15)


def make_shelf(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    width, depth = rng.uniform(0.8, 1.2), rng.uniform(0.30, 0.42)
    rows = int(rng.integers(2, 7))
    while rows >= 2 and rows * FOLDER_HEIGHT_M + 0.07 > headroom_m - 0.05:
        rows -= 1
    if rows < 2:
        return None
    height, board = rows * FOLDER_HEIGHT_M + 0.07, 0.019
    b = MeshBuilder()
    for sx in (-1, 1):
        x = sx * (width / 2 - board / 2)
        b.box((x - board / 2, -depth / 2, 0.0), (x + board / 2, depth / 2, height))
    inner = width / 2 - board
    b.box((-inner, depth / 2 - 0.01, 0.05), (inner, depth / 2, height - board))  # back panel
    b.box((-inner, -depth / 2, 0.0), (inner, depth / 2 - 0.01, 0.05))  # plinth
    for r in range(rows + 1):
        z = 0.05 + r * FOLDER_HEIGHT_M
        b.box((-inner, -depth / 2, z), (inner, depth / 2 - 0.01, min(z + board, height)))
        if r < rows and rng.random() < 0.8:
            _files(b, rng, -inner + 0.01, inner - 0.01, -depth / 2 + 0.03, depth / 2 - 0.02, z + board,
                   FOLDER_HEIGHT_M - board - 0.02)
    return _finish(b, "Clutter.Shelf")


def make_cabinet(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    variant = rng.integers(3)
    if variant == 0:  # desk pedestal, three drawers
        width, depth, height, fronts = rng.uniform(0.40, 0.45), rng.uniform(0.55, 0.60), rng.uniform(0.60, 0.72), 3
    elif variant == 1:  # filing cabinet, three or four drawers
        fronts = int(rng.integers(3, 5))
        width, depth, height = rng.uniform(0.45, 0.50), rng.uniform(0.62, 0.70), 0.34 * fronts
    else:  # cupboard, 2-5 folder heights
        fronts = int(rng.integers(2, 6))
        width, depth, height = rng.uniform(0.8, 1.2), rng.uniform(0.42, 0.47), fronts * FOLDER_HEIGHT_M + 0.05
    if height > headroom_m - 0.05:
        return None
    b = MeshBuilder()
    b.box((-width / 2 + 0.02, -depth / 2 + 0.03, 0.0), (width / 2 - 0.02, depth / 2, 0.05))  # plinth
    b.box((-width / 2, -depth / 2 + 0.02, 0.05), (width / 2, depth / 2, height))
    step = (height - 0.05) / fronts
    for k in range(fronts):  # handles on the front (-y)
        z = 0.05 + (k + 0.75) * step
        b.box((-0.06, -depth / 2, z - 0.01), (0.06, -depth / 2 + 0.02, z + 0.01))
    return _finish(b, "Clutter.Cabinet")


def make_whiteboard(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    if against_wall and rng.random() < 0.7:  # hung on the wall, its back at +y
        width, board_h, bottom = rng.uniform(1.2, 2.4), rng.uniform(0.9, 1.2), rng.uniform(0.85, 1.0)
        if bottom + board_h > headroom_m - 0.05:
            return None
        b = MeshBuilder()
        b.box((-width / 2, -0.02, bottom), (width / 2, 0.0, bottom + board_h))
        b.box((-width / 2 + 0.1, -0.08, bottom - 0.03), (width / 2 - 0.1, -0.02, bottom))  # pen tray
        return _finish(b, "Clutter.Whiteboard", on_floor=False)
    width, board_h, bottom = rng.uniform(1.2, 1.8), rng.uniform(0.9, 1.2), rng.uniform(0.75, 0.9)
    top = bottom + board_h + 0.1
    if top > headroom_m - 0.05:
        return None
    b = MeshBuilder()
    b.box((-width / 2, -0.015, bottom), (width / 2, 0.015, bottom + board_h))
    b.box((-width / 2 + 0.1, -0.07, bottom - 0.02), (width / 2 - 0.1, -0.015, bottom))  # pen tray
    foot = rng.uniform(0.25, 0.3)
    for sx in (-1, 1):
        x = sx * (width / 2 + 0.03)
        b.box((x - 0.02, -0.02, 0.06), (x + 0.02, 0.02, top))
        b.box((x - 0.025, -foot, 0.04), (x + 0.025, foot, 0.08))
        for sy in (-1, 1):
            b.prism((x, sy * (foot - 0.03), 0.0), (x, sy * (foot - 0.03), 0.04), 0.025, sides=8)
    return _finish(b, "Clutter.Whiteboard")


# ------------------------------------------------------------------------- under the ceiling

def make_ceiling_light(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    b = MeshBuilder()
    if rng.random() < 0.35:  # a linear pendant on two cables
        length, width, body = rng.uniform(1.15, 1.6), rng.uniform(0.06, 0.3), rng.uniform(0.04, 0.1)
        drop = min(rng.uniform(0.3, 0.9), headroom_m - MIN_CLEAR_UNDER_FIXTURE_M - body)
        if drop >= 0.2:  # else the ceiling is too low for a pendant: a panel
            b.box((-length / 2, -width / 2, 0.0), (length / 2, width / 2, body))
            for side in (-1, 1):
                x = side * (length / 2 - 0.1)
                b.box((x - CABLE_M / 2, -CABLE_M / 2, body), (x + CABLE_M / 2, CABLE_M / 2, body + drop))
            return _finish(b, "Fixture.Luminaire")
    width, depth = CEILING_MODULES_M[int(rng.integers(len(CEILING_MODULES_M)))]
    height = rng.uniform(0.012, 0.1)  # a recessed troffer's trim to a surface-mounted box
    diffuser = 0.008 if height > 0.04 else 0.0  # a surface-mounted box's diffuser stands proud of it
    if headroom_m - height - diffuser < MIN_CLEAR_UNDER_FIXTURE_M:
        return None
    b.box((-width / 2, -depth / 2, 0.0), (width / 2, depth / 2, height))
    if diffuser:
        b.box((-width / 2 + 0.03, -depth / 2 + 0.03, -diffuser), (width / 2 - 0.03, depth / 2 - 0.03, 0.0))
    return _finish(b, "Fixture.Luminaire")


def recessed_troffer(rng: np.random.Generator, panel: ClutterObject) -> ClutterObject:
    """``panel`` (a ceiling light's panel) as a lay-in troffer set into a suspended ceiling: its
    louvre or diffuser ``TROFFER_RECESS_M`` above the ceiling's underside (z = 0 here), the
    opening lined by a trim, the housing above. The ceiling is cut where it stands (placement)."""
    width, depth = panel.size_m[0], panel.size_m[1]
    recess, housing = rng.uniform(*TROFFER_RECESS_M), rng.uniform(*TROFFER_HOUSING_M)
    b = MeshBuilder()
    b.box((-width / 2, -depth / 2, recess), (width / 2, depth / 2, recess + housing))
    t = TRIM_M
    for sx in (-1, 1):  # the trim lines the opening, from the ceiling's underside up to the louvre
        b.box((sx * width / 2 - (t if sx > 0 else 0.0), -depth / 2, 0.0),
              (sx * width / 2 + (t if sx < 0 else 0.0), depth / 2, recess))
    for sy in (-1, 1):
        b.box((-width / 2 + t, sy * depth / 2 - (t if sy > 0 else 0.0), 0.0),
              (width / 2 - t, sy * depth / 2 + (t if sy < 0 else 0.0), recess))
    return _finish(b, "Fixture.Luminaire")


def make_downlight(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    diameter, proud = rng.uniform(0.12, 0.25), rng.uniform(0.005, 0.03)
    if headroom_m - proud < MIN_CLEAR_UNDER_FIXTURE_M:
        return None
    b = MeshBuilder()
    b.prism((0.0, 0.0, 0.0), (0.0, 0.0, proud), diameter / 2, sides=16)
    return _finish(b, "Fixture.Luminaire")


def make_air_terminal(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    face, below = rng.uniform(0.3, 0.625), rng.uniform(0.02, 0.06)
    if headroom_m - below < MIN_CLEAR_UNDER_FIXTURE_M:
        return None
    b = MeshBuilder()
    flange = 0.008
    b.box((-face / 2, -face / 2, below - flange), (face / 2, face / 2, below))  # the face plate
    steps = int(rng.integers(2, 4))  # stepped cones, each smaller and lower
    for k in range(steps):
        half = face / 2 * (1.0 - 0.6 * (k + 1) / steps) + 0.02
        z1 = below - flange - k * (below - flange) / steps
        b.box((-half, -half, z1 - (below - flange) / steps), (half, half, z1))
    return _finish(b, "Fixture.AirTerminal")


# ------------------------------------------------------------------------------ site materials

def _pallet(b: MeshBuilder, z: float, dx: float = 0.0, dy: float = 0.0) -> float:
    """A EUR pallet (EN 13698-1, 1.20 x 0.80 x 0.144 m) with its corner at (dx, dy, z); returns its top z."""
    length, width = 1.2, 0.8
    for k in range(3):  # bottom boards along the length
        y = dy + k * (width - 0.1) / 2
        b.box((dx, y, z), (dx + length, y + 0.1, z + 0.022))
    for i in range(3):  # nine blocks
        for k in range(3):
            x, y = dx + i * (length - 0.145) / 2, dy + k * (width - 0.1) / 2
            b.box((x, y, z + 0.022), (x + 0.145, y + 0.1, z + 0.1))
    for k in range(3):  # stringer boards across the blocks
        y = dy + k * (width - 0.1) / 2
        b.box((dx, y, z + 0.1), (dx + length, y + 0.1, z + 0.122))
    for k in range(5):  # top deck boards
        y = dy + k * (width - 0.1) / 4
        b.box((dx, y, z + 0.122), (dx + length, y + 0.1, z + 0.144))
    return z + 0.144


def make_material_stack(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    b = MeshBuilder()
    if rng.random() < 0.5:  # wrapped blocks or bags on a pallet
        top = _pallet(b, 0.0)
        load = min(rng.uniform(0.4, 1.0), headroom_m - 0.2 - top)
        if load < 0.2:
            return None
        inset = rng.uniform(0.0, 0.03)
        b.box((inset, inset, top), (1.2 - inset, 0.8 - inset, top + load))
    else:  # boards (plasterboard, EN 520: 1.2 m wide) on three bearers
        length, stack = rng.uniform(2.0, 3.0), rng.uniform(0.1, 0.5)
        for k in range(3):
            x = 0.15 + k * (length - 0.4) / 2
            b.box((x, 0.0, 0.0), (x + 0.1, 1.2, 0.1))
        b.box((0.0, 0.0, 0.1), (length, 1.2, 0.1 + stack))
    return _finish(b, "Clutter.MaterialStack")


def make_pallet(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    b = MeshBuilder()
    z = 0.0
    for _ in range(int(rng.integers(1, 7))):
        if z + 0.144 > headroom_m - 0.1:
            break
        z = _pallet(b, z, rng.uniform(0.0, 0.02), rng.uniform(0.0, 0.02))
    return _finish(b, "Clutter.Pallet")


def make_box(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    b = MeshBuilder()
    z = 0.0
    width, depth = rng.uniform(0.35, 0.8), rng.uniform(0.3, 0.6)
    for k in range(int(rng.integers(1, 4))):
        height = rng.uniform(0.25, 0.55)
        if z + height > min(1.5, headroom_m - 0.1):
            break
        w, d = width * rng.uniform(0.75, 1.0) if k else width, depth * rng.uniform(0.75, 1.0) if k else depth
        x, y = rng.uniform(0, width - w + 1e-9), rng.uniform(0, depth - d + 1e-9)
        b.box((x, y, z), (x + w, y + d, z + height))
        z += height
    return _finish(b, "Clutter.Box")


def make_bucket(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    if rng.random() < 0.75:  # builder's bucket, 10-20 l
        diameter, height = rng.uniform(0.26, 0.34), rng.uniform(0.25, 0.38)
    else:  # mortar tub, 65-90 l
        diameter, height = rng.uniform(0.55, 0.65), rng.uniform(0.30, 0.40)
    b = MeshBuilder()
    b.prism((0.0, 0.0, 0.0), (0.0, 0.0, height), diameter / 2 / math.cos(math.pi / 16), sides=16)
    return _finish(b, "Clutter.Bucket")


def make_cable_drum(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    diameter, width = rng.uniform(0.5, 1.0), rng.uniform(0.3, 0.7)
    flange = rng.uniform(0.04, 0.06)
    wound = diameter * rng.uniform(0.6, 0.9)
    radius = diameter / 2 / math.cos(math.pi / 20)  # the 20-gon's inscribed circle is the flange's
    b = MeshBuilder()
    standing = rng.random() < 0.6
    axis = (lambda s: (s, 0.0, radius)) if standing else (lambda s: (0.0, 0.0, s + width / 2))
    b.prism(axis(-width / 2), axis(-width / 2 + flange), radius, sides=20)
    b.prism(axis(width / 2 - flange), axis(width / 2), radius, sides=20)
    b.prism(axis(-width / 2 + flange), axis(width / 2 - flange), wound / 2, sides=20)
    return _finish(b, "Clutter.CableDrum")


def make_waste_bin(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    width, depth, height = ((0.48, 0.55, 0.93), (0.58, 0.73, 1.07), (0.60, 0.88, 1.10))[int(rng.integers(3))]
    scale = rng.uniform(0.97, 1.03)
    width, depth, height = width * scale, depth * scale, height * scale
    b = MeshBuilder()
    wheel = 0.1
    b.box((-width / 2 + 0.03, -depth / 2, 0.03), (width / 2 - 0.03, depth / 2 - 0.1, height - 0.04))  # body
    b.box((-width / 2, -depth / 2 - 0.01, height - 0.04), (width / 2, depth / 2 - 0.04, height))  # lid
    b.box((-width / 2 + 0.05, depth / 2 - 0.1, height - 0.12), (width / 2 - 0.05, depth / 2, height - 0.08))  # handle
    for sx in (-1, 1):
        x = sx * (width / 2 - 0.04)
        b.prism((x - sx * 0.0, depth / 2 - 0.1, wheel), (x + sx * 0.04, depth / 2 - 0.1, wheel), wheel, sides=12)
    return _finish(b, "Clutter.WasteBin")


# ------------------------------------------------------------------------------ temporary works

def make_ladder(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    b = MeshBuilder()
    spacing = rng.uniform(0.25, 0.30)
    if against_wall and rng.random() < 0.6:  # a leaning ladder at 75 degrees, its top at the wall (+y)
        angle = math.radians(75.0)
        length = rng.uniform(2.0, 4.0)
        length = min(length, (headroom_m - 0.1) / math.sin(angle))
        if length < 2.0:
            return None
        width, rise, run = rng.uniform(0.38, 0.45), length * math.sin(angle), length * math.cos(angle)
        for sx in (-1, 1):
            x = sx * (width / 2 - 0.0125)
            b.member((x, -run, 0.0), (x, 0.0, rise), 0.025, 0.07)
        for k in range(1, int(length / spacing)):
            t = k * spacing / length
            b.member((-width / 2 + 0.025, -run * (1 - t), rise * t), (width / 2 - 0.025, -run * (1 - t), rise * t),
                     0.03, 0.025)
        return _finish(b, "Temporary.Ladder")
    steps = int(rng.integers(3, 9))
    while steps >= 3 and (steps + 1) * spacing > headroom_m - 0.1:
        steps -= 1
    if steps < 3:
        return None
    height = (steps + 1) * spacing
    splay = math.tan(math.radians(rng.uniform(12.0, 16.0))) * height  # each leg's run at the floor
    width = rng.uniform(0.42, 0.5)
    for sx in (-1, 1):
        x = sx * (width / 2 + 0.04 - 0.0125)
        b.member((x, -splay, 0.0), (x, 0.0, height - 0.04), 0.025, 0.07)  # front stiles
        b.member((x, splay, 0.0), (x, 0.05, height - 0.04), 0.025, 0.04)  # rear legs
    for k in range(1, steps + 1):
        t = k * spacing / height
        y = -splay * (1 - t)
        b.box((-width / 2 + 0.02, y - 0.04, t * height - 0.02), (width / 2 - 0.02, y + 0.04, t * height))
    b.box((-width / 2, -0.06, height - 0.04), (width / 2, 0.1, height))  # top cap
    return _finish(b, "Temporary.Ladder")


def make_trestle(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    height = min(rng.uniform(0.6, 1.2), headroom_m - 0.3)
    if height < 0.6:
        return None
    span, across = rng.uniform(2.4, 3.0), rng.uniform(0.8, 1.0)
    boards = int(rng.integers(2, 4))
    b = MeshBuilder()
    for x in (0.3, span - 0.3):  # two trestles: a bar across, legs splayed along the boards
        b.box((x - 0.03, 0.0, height - 0.06), (x + 0.03, across, height))
        splay = rng.uniform(0.2, 0.3)
        for y in (0.05, across - 0.05):
            b.member((x - splay, y, 0.0), (x, y, height - 0.06), 0.04, 0.04)
            b.member((x + splay, y, 0.0), (x + 0.0, y, height - 0.06), 0.04, 0.04)
    start = (across - boards * 0.225) / 2
    for k in range(boards):  # scaffold boards (BS 2482, 225 x 38 mm)
        y = start + k * 0.225
        b.box((0.0, y + 0.003, height), (span, y + 0.222, height + 0.038))
    return _finish(b, "Temporary.Trestle")


def make_scaffold_tower(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    guard, castor = 1.0, 0.15
    platform = min(rng.uniform(0.8, 3.0), headroom_m - 0.05 - guard - 0.05)
    if platform < 0.6:
        return None
    width = (0.75 if rng.random() < 0.5 else 1.35) + rng.uniform(-0.05, 0.05)
    length = float(rng.choice([1.8, 2.0, 2.5])) + rng.uniform(-0.03, 0.03)
    top = platform + guard + 0.05
    tube = 0.025  # 50 mm aluminium tubes
    b = MeshBuilder()
    corners = [(sx * length / 2, sy * width / 2) for sx in (-1, 1) for sy in (-1, 1)]
    for x, y in corners:
        b.prism((x, y, 0.0), (x, y, castor), 0.075, sides=10)  # castor
        b.prism((x, y, castor), (x, y, top), tube, sides=8)  # upright
    inner_y = width / 2 - tube
    for sx in (-1, 1):  # end frames with rungs every 0.28 m (the access ladder)
        x = sx * length / 2
        z = castor + 0.28
        while z < top - 0.05:
            b.prism((x, -inner_y, z), (x, inner_y, z), 0.02, sides=8)
            z += 0.28
    inner_x = length / 2 - tube
    for sy in (-1, 1):  # long sides: a horizontal at the base and a diagonal brace
        y = sy * width / 2
        b.prism((-inner_x, y, castor + 0.2), (inner_x, y, castor + 0.2), 0.02, sides=8)
        b.prism((-inner_x, y, castor + 0.25), (inner_x, y, max(platform - 0.1, castor + 0.5)), 0.02, sides=8)
    b.box((-inner_x, -inner_y, platform - 0.06), (inner_x, inner_y, platform))  # platform deck
    for z in (platform + 0.5, platform + guard):  # intermediate and principal guardrails
        for sy in (-1, 1):
            b.prism((-inner_x, sy * width / 2, z), (inner_x, sy * width / 2, z), 0.02, sides=8)
    for sy in (-1, 1):  # toe boards 0.15 m high
        y = sy * (inner_y - 0.015)
        b.box((-inner_x, y - 0.012, platform), (inner_x, y + 0.012, platform + 0.15))
    return _finish(b, "Temporary.ScaffoldTower")


def make_prop(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    """A prop wedged between the floor and the soffit above (its top plate 5 mm below it)."""
    height = headroom_m - 0.005
    if not 1.04 <= height <= 5.5:
        return None
    b = MeshBuilder()
    b.box((-0.075, -0.075, 0.0), (0.075, 0.075, 0.008))
    b.box((-0.075, -0.075, height - 0.008), (0.075, 0.075, height))
    outer = 0.008 + (height - 0.016) * rng.uniform(0.45, 0.6)
    b.prism((0.0, 0.0, 0.008), (0.0, 0.0, outer), 0.03, sides=12)
    b.prism((0.0, 0.0, outer), (0.0, 0.0, height - 0.008), 0.024, sides=12)
    b.prism((0.0, 0.0, outer - 0.06), (0.0, 0.0, outer), 0.05, sides=6)  # the adjusting collar nut
    return _finish(b, "Temporary.Prop")


# ------------------------------------------------------------------------------------ people

def make_person(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    """A standing or walking person facing -y, proportions after Drillis & Contini (1966)."""
    stature = rng.uniform(1.49, 1.91)
    if stature > headroom_m - 0.05:
        return None
    h = stature
    walking = rng.random() < 0.5
    swing = math.radians(rng.uniform(15.0, 25.0)) if walking else 0.0
    ankle, hip, shoulder, chin = 0.039 * h, 0.530 * h, 0.818 * h, 0.870 * h
    leg = hip - ankle
    drop = leg * (1 - math.cos(swing))  # the spread legs lower the hips
    b = MeshBuilder()
    for side, sign in ((-1, 1), (1, -1)):  # (x side, leg forward or back)
        x = side * 0.05 * h
        foot_y = -sign * leg * math.sin(swing)
        b.member((x, 0.0, hip - drop), (x, foot_y, ankle), 0.075 * h, 0.08 * h)  # leg
        b.box((x - 0.0275 * h, foot_y - 0.11 * h, 0.0), (x + 0.0275 * h, foot_y + 0.042 * h, ankle))  # foot
    b.box((-0.095 * h, -0.055 * h, hip - drop - 0.04 * h), (0.095 * h, 0.055 * h, 0.63 * h - drop))  # pelvis
    b.box((-0.12 * h, -0.065 * h, 0.63 * h - drop), (0.12 * h, 0.065 * h, shoulder - drop))  # chest
    b.box((-0.025 * h, -0.025 * h, shoulder - drop), (0.025 * h, 0.025 * h, chin - drop))  # neck
    b.box((-0.045 * h, -0.0575 * h, chin - drop), (0.045 * h, 0.0575 * h, h - drop))  # head
    arm = 0.44 * h  # upper arm + forearm + hand
    for side, sign in ((-1, -1), (1, 1)):  # arms swing against the legs
        x = side * 0.13 * h
        top = shoulder - 0.02 * h - drop
        angle = 0.8 * swing * sign
        out = math.radians(2.0)
        b.member((x, 0.0, top), (x + side * arm * math.sin(out), -arm * math.sin(angle), top - arm * math.cos(angle)),
                 0.045 * h, 0.05 * h)
    return _finish(b, "Person.Walking" if walking else "Person.Standing")


def make_site_container(rng: np.random.Generator, headroom_m: float, against_wall: bool) -> ClutterObject | None:
    """A site container (ISO 668 series 1: 2.438 m wide, 2.591 m high; 10 ft = 2.991 m or 20 ft =
    6.058 m long), a closed box on two 0.1 m bearers. Stands outside only (``site.ground``)."""
    length = 2.991 if rng.random() < 0.4 else 6.058
    b = MeshBuilder()
    b.box((0.0, 0.0, 0.1), (length, 2.438, 2.591))
    for x in (0.3, length - 0.5):  # bearers under the corner castings
        b.box((x, 0.0, 0.0), (x + 0.2, 2.438, 0.1))
    return _finish(b, "Temporary.Container")


CLUTTER_KINDS: dict[str, ClutterKind] = {k.name: k for k in (
    ClutterKind("desk", "office", ("Clutter.Desk",), 3.0, 0.7, False, ((1.2, 1.8), (0.7, 0.9), (0.72, 1.22)),
                make_desk),
    ClutterKind("chair", "office", ("Clutter.Chair",), 2.0, 0.1, True, ((0.6, 0.72), (0.58, 0.7), (0.8, 1.12)),
                make_chair),
    ClutterKind("sofa", "office", ("Clutter.Sofa",), 0.6, 0.8, False, ((1.5, 2.2), (0.8, 0.95), (0.75, 0.9)),
                make_sofa),
    ClutterKind("shelf", "office", ("Clutter.Shelf",), 1.5, 1.0, False, ((0.8, 1.2), (0.3, 0.42), (0.82, 2.32)),
                make_shelf),
    ClutterKind("cabinet", "office", ("Clutter.Cabinet",), 2.0, 0.8, False, ((0.4, 1.2), (0.42, 0.7), (0.6, 1.93)),
                make_cabinet),
    ClutterKind("whiteboard", "office", ("Clutter.Whiteboard",), 0.8, 0.8, False,
                ((1.2, 2.4), (0.08, 0.6), (1.75, 2.2)), make_whiteboard),
    ClutterKind("ceiling_light", "ceiling", ("Fixture.Luminaire",), 0.0, 0.0, False,
                ((0.3, 1.6), (0.06, 0.625), (0.012, 1.0)), make_ceiling_light,
                mount="ceiling", spacing_m=(1.8, 2.7), room_probability=0.9, lay_in=True),
    ClutterKind("downlight", "ceiling", ("Fixture.Luminaire",), 0.0, 0.0, False,
                ((0.11, 0.25), (0.11, 0.25), (0.005, 0.03)), make_downlight,
                mount="ceiling", spacing_m=(1.2, 1.8), room_probability=0.25),
    ClutterKind("air_terminal", "ceiling", ("Fixture.AirTerminal",), 0.0, 0.0, False,
                ((0.3, 0.625), (0.3, 0.625), (0.02, 0.06)), make_air_terminal,
                mount="ceiling", spacing_m=(3.0, 4.5), room_probability=0.6),
    ClutterKind("material_stack", "site", ("Clutter.MaterialStack",), 2.0, 0.5, False,
                ((1.2, 3.0), (0.8, 1.2), (0.2, 1.15)), make_material_stack),
    ClutterKind("pallet", "site", ("Clutter.Pallet",), 1.0, 0.5, False, ((1.2, 1.22), (0.8, 0.82), (0.144, 0.864)),
                make_pallet),
    ClutterKind("box", "site", ("Clutter.Box",), 2.0, 0.5, True, ((0.35, 0.8), (0.3, 0.6), (0.25, 1.5)), make_box),
    ClutterKind("bucket", "site", ("Clutter.Bucket",), 2.0, 0.3, True, ((0.26, 0.67), (0.26, 0.67), (0.25, 0.4)),
                make_bucket),
    ClutterKind("cable_drum", "site", ("Clutter.CableDrum",), 0.7, 0.3, True, ((0.3, 1.02), (0.3, 1.02), (0.3, 1.02)),
                make_cable_drum),
    ClutterKind("waste_bin", "site", ("Clutter.WasteBin",), 0.7, 0.7, False,
                ((0.46, 0.62), (0.53, 0.92), (0.9, 1.14)), make_waste_bin),
    ClutterKind("ladder", "site", ("Temporary.Ladder",), 1.0, 0.5, False, ((0.38, 0.58), (0.45, 1.6), (1.0, 3.87)),
                make_ladder),
    ClutterKind("trestle", "site", ("Temporary.Trestle",), 0.7, 0.3, False, ((2.4, 3.04), (0.8, 1.0), (0.638, 1.24)),
                make_trestle),
    ClutterKind("scaffold_tower", "site", ("Temporary.ScaffoldTower",), 0.5, 0.2, False,
                ((1.9, 2.7), (0.85, 1.55), (1.65, 4.05)), make_scaffold_tower),
    ClutterKind("prop", "site", ("Temporary.Prop",), 1.0, 0.0, False, ((0.15, 0.15), (0.15, 0.15), (1.035, 5.5)),
                make_prop),
    ClutterKind("person", "people", ("Person.Standing", "Person.Walking"), 1.0, 0.0, True,
                ((0.49, 0.66), (0.2, 1.1), (1.42, 1.91)), make_person),
)}


def check_kinds(kinds: Iterable[str]) -> None:
    """Raise ConfigError for a name that is neither a kind nor a group."""
    for name in kinds:
        if name not in CLUTTER_KINDS and name not in GROUPS:
            raise ConfigError(f"unknown clutter kind {name!r}; give kinds ({', '.join(CLUTTER_KINDS)}) or groups "
                              f"({', '.join(GROUPS)})")


def select_kinds(kinds: Iterable[str]) -> tuple[ClutterKind, ...]:
    """The kinds named (groups expanded), in library order."""
    names = set(kinds)
    return tuple(k for k in CLUTTER_KINDS.values() if k.name in names or k.group in names)
