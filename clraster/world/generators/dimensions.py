"""Dimensions of the :func:`~clraster.scenes.plant` building (metres, +Y up).

Shared by the equipment (which reaches from floor to ceiling, or climbs a storey) and by
the layout and its cameras (:mod:`clraster.scenes.building`).
"""

# -- plant dimensions (metres) ----------------------------------------------------------
# plant_inside_camera recovers the layout from the scene's bounds with these, so changing
# one changes both the generator and the camera.
ROOM_X = 8.0  #: room pitch along x (corridor direction), partition wall centre to centre
ROOM_Z = 7.0  #: room depth, from the corridor wall's centre line to the far wall's
CORRIDOR = 3.0  #: corridor pitch across z (clear width CORRIDOR − WALL)
BAND = 2.0 * ROOM_Z + CORRIDOR  #: a row of rooms, a corridor, a row of rooms
STOREY = 5.0  #: floor-to-floor height
SLAB = 0.3  #: floor / ceiling slab thickness (a slab's top is its storey's floor, y = k·STOREY)
WALL = 0.2  #: partition wall thickness (centred on its grid line)
OUTER = 0.3  #: outer wall thickness (inside the footprint)
CLEAR = STOREY - SLAB  #: clear height of a storey
EYE_HEIGHT = 1.7  #: eye height of the first-person camera above its floor
