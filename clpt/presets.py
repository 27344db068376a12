"""Named material presets, as plain data.

A preset is a dict of Material fields. White, red and green are the Cornell
box colours of Mitsuba 3's ``cornell_box()`` (linear RGB), so a scene built
from presets matches that renderer's reference scene.
"""

CBOX_WHITE = (0.885809, 0.698859, 0.666422)
CBOX_RED = (0.570068, 0.0430135, 0.0443706)
CBOX_GREEN = (0.105421, 0.37798, 0.076425)

PRESETS = {
    # diffuse
    "white": {"kd": CBOX_WHITE},
    "red": {"kd": CBOX_RED},
    "green": {"kd": CBOX_GREEN},
    "blue": {"kd": (0.05, 0.12, 0.55)},
    "gray": {"kd": (0.5, 0.5, 0.5)},
    "black": {},
    # Phong: a white diffuse base under a sharp highlight
    "glossy": {"kd": (0.35, 0.35, 0.35), "ks": (0.6, 0.6, 0.6), "shininess": 200.0},
    "glossy_red": {"kd": (0.45, 0.03, 0.03), "ks": (0.5, 0.5, 0.5), "shininess": 120.0},
    # perfect mirror
    "mirror": {"kr": (1.0, 1.0, 1.0)},
    # dielectrics: kt is the colour of the transmitted light, Fresnel splits
    # reflection and refraction at the interface
    "glass": {"kt": (1.0, 1.0, 1.0), "ior": 1.5},
    "green_glass": {"kt": (0.25, 0.9, 0.35), "ior": 1.5},
    "diamond": {"kt": (1.0, 1.0, 1.0), "ior": 2.42},
    # the paper's dual-natured glass: Russian roulette picks a perfect mirror
    # or a refracting interface at each hit
    "dual_glass": {"kr": (0.35, 0.35, 0.35), "kt": (0.65, 0.65, 0.65), "ior": 1.5},
}
