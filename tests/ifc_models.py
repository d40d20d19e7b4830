"""IFC building models written with IfcOpenShell's own API, as BIM tools export them: walls, slabs
and a roof around rooms, windows and a door in openings, a partition, a free-standing column and
furniture inside, rooms as IfcSpace, a site with its terrain, and a second building (a garage).

Every size is a round number so that the envelope's volume is known without meshsom:
the house is ``HOUSE`` (outer length, width, height from the floor slab's underside to the roof's
top), the garage ``GARAGE``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: Outer size of the house (x, y, z), metres: walls 0.3 thick standing on a 0.3 m floor slab
#: under a 0.3 m roof slab, both covering the whole outline.
HOUSE = (10.0, 8.0, 3.6)
#: Outer size of the garage, 2 m east of the house.
GARAGE = (4.0, 6.0, 2.8)
GARAGE_AT = (12.0, 0.0)
#: Where IfcMapConversion puts the model's origin (IFC4 files written with ``georeferenced``).
EASTINGS, NORTHINGS, HEIGHT = 465_000.0, 5_428_000.0, 110.0
ROTATION_DEG = 30.0
CRS_NAME = "EPSG:25832"


def _placement(x, y, z, angle=0.0):
    m = np.eye(4)
    c, s = math.cos(angle), math.sin(angle)
    m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    m[:3, 3] = [x, y, z]
    return m


def write_house(path: Path, schema: str = "IFC4", georeferenced: bool = True, garage: bool = True,
                openings: bool = True, roof_gap: float = 0.0, building: bool = True) -> Path:
    """Write the two buildings to ``path`` (IFC, ``schema`` "IFC2X3", "IFC4" or "IFC4X3").

    ``roof_gap``: the roof slabs lie this far above the walls' tops (a hairline gap, metres);
    ``building``: False puts the storeys straight under the site, with no IfcBuilding."""
    import ifcopenshell.api as api
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.context
    import ifcopenshell.api.feature
    import ifcopenshell.api.geometry
    import ifcopenshell.api.georeference
    import ifcopenshell.api.project
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial
    import ifcopenshell.api.unit  # noqa: F401 (each API module is imported by name)

    m = api.project.create_file(version=schema)
    if schema == "IFC2X3":  # every rooted entity has an owner history there
        import ifcopenshell.api.owner.settings as owner  # (imports ifcopenshell.api.owner too)

        user = api.owner.add_person_and_organisation(
            m, person=api.owner.add_person(m), organisation=api.owner.add_organisation(m))
        application = api.owner.add_application(m)
        saved = owner.get_user, owner.get_application
        owner.get_user, owner.get_application = (lambda f: user), (lambda f: application)
        try:
            return _write(m, api, path, schema, georeferenced, garage, openings, roof_gap, building)
        finally:
            owner.get_user, owner.get_application = saved
    return _write(m, api, path, schema, georeferenced, garage, openings, roof_gap, building)


def _project(m, api, name):
    """The project of a new file ``m`` (metres), its body context and its site: (body, site)."""
    project = api.root.create_entity(m, ifc_class="IfcProject", name=name)
    api.unit.assign_unit(m)
    model = api.context.add_context(m, context_type="Model")
    body = api.context.add_context(m, context_type="Model", context_identifier="Body", target_view="MODEL_VIEW",
                                   parent=model)
    site = api.root.create_entity(m, ifc_class="IfcSite", name="site")
    api.aggregate.assign_object(m, relating_object=project, products=[site])
    return body, site


def _write(m, api, path, schema, georeferenced, garage, openings, roof_gap, building):
    body, site = _project(m, api, "meshsom test")
    # the terrain: a 40 x 40 m plate under both buildings (IfcSite geometry, never a building)
    terrain = api.geometry.add_slab_representation(m, context=body, depth=0.5,
                                                   polyline=[(-15, -15), (25, -15), (25, 25), (-15, 25)])
    api.geometry.assign_representation(m, product=site, representation=terrain)
    api.geometry.edit_object_placement(m, product=site, matrix=_placement(0, 0, -0.8))
    if georeferenced and schema != "IFC2X3":
        api.georeference.add_georeferencing(m)
        a = math.radians(ROTATION_DEG)
        api.georeference.edit_georeferencing(
            m, projected_crs={"Name": CRS_NAME},
            coordinate_operation={"Eastings": EASTINGS, "Northings": NORTHINGS, "OrthogonalHeight": HEIGHT,
                                  "XAxisAbscissa": math.cos(a), "XAxisOrdinate": math.sin(a), "Scale": 1.0})

    def element(ifc_class, container, rep, at, name=None):
        e = api.root.create_entity(m, ifc_class=ifc_class, name=name or ifc_class)
        api.geometry.assign_representation(m, product=e, representation=rep)
        api.geometry.edit_object_placement(m, product=e, matrix=at)
        if ifc_class == "IfcSpace":  # a spatial element: part of the storey, not contained in it
            api.aggregate.assign_object(m, relating_object=container, products=[e])
        else:
            api.spatial.assign_container(m, relating_structure=container, products=[e])
        return e

    def block(name, x0, y0, size, slab=0.3, wall=0.3, doors=()):
        """Outer walls, floor and roof slabs of a box ``size`` from (x0, y0, -slab)."""
        storey = api.root.create_entity(m, ifc_class="IfcBuildingStorey", name=f"{name} ground floor")
        if building:
            parent = api.root.create_entity(m, ifc_class="IfcBuilding", name=name)
            api.aggregate.assign_object(m, relating_object=site, products=[parent])
            api.aggregate.assign_object(m, relating_object=parent, products=[storey])
        else:
            api.aggregate.assign_object(m, relating_object=site, products=[storey])
        lx, ly, lz = size
        h = lz - 2 * slab
        outline = [(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)]
        element("IfcSlab", storey, api.geometry.add_slab_representation(m, context=body, depth=slab, polyline=outline),
                _placement(0, 0, -slab), "floor")
        roof = api.root.create_entity(m, ifc_class="IfcRoof", name="roof")  # geometry in its slab
        api.spatial.assign_container(m, relating_structure=storey, products=[roof])
        roof_slab = api.root.create_entity(m, ifc_class="IfcSlab", name="roof slab")
        api.geometry.assign_representation(m, product=roof_slab, representation=api.geometry.add_slab_representation(
            m, context=body, depth=slab, polyline=outline))
        api.geometry.edit_object_placement(m, product=roof_slab, matrix=_placement(0, 0, h + roof_gap))
        api.aggregate.assign_object(m, relating_object=roof, products=[roof_slab])
        walls = []
        # four walls along the outline, each along its own x axis, the outer face on the outline
        for (ax, ay), (bx, by) in zip(outline, outline[1:] + outline[:1]):
            angle = math.atan2(by - ay, bx - ax)
            length = math.hypot(bx - ax, by - ay)
            rep = api.geometry.add_wall_representation(m, context=body, length=length, height=h, thickness=wall)
            walls.append(element("IfcWall", storey, rep, _placement(ax, ay, 0, angle)))
        for k, (along, width, height, cls) in enumerate(doors):
            if not openings:
                break
            opening = api.root.create_entity(m, ifc_class="IfcOpeningElement", name=f"opening {k}")
            rep = api.geometry.add_wall_representation(m, context=body, length=width, height=height, thickness=wall)
            api.geometry.assign_representation(m, product=opening, representation=rep)
            api.geometry.edit_object_placement(m, product=opening, matrix=_placement(x0 + along, y0, 0.9 if cls == "IfcWindow" else 0))
            api.feature.add_feature(m, feature=opening, element=walls[0])
            fill = api.root.create_entity(m, ifc_class=cls, name=cls)
            frame = api.geometry.add_wall_representation(m, context=body, length=width, height=height, thickness=0.1)
            api.geometry.assign_representation(m, product=fill, representation=frame)
            api.geometry.edit_object_placement(m, product=fill, matrix=_placement(x0 + along, y0 + 0.1, 0.9 if cls == "IfcWindow" else 0))
            api.spatial.assign_container(m, relating_structure=storey, products=[fill])
            api.feature.add_filling(m, opening=opening, element=fill)
        return storey, h

    storey, h = block("house", 0.0, 0.0, HOUSE, doors=[(1.0, 1.2, 1.2, "IfcWindow"), (4.0, 1.0, 2.1, "IfcDoor"),
                                                        (7.0, 1.2, 1.2, "IfcWindow")])
    # inside: a partition wall (touching the outer walls), a free-standing column and a table (furniture)
    rep = api.geometry.add_wall_representation(m, context=body, length=HOUSE[1] - 0.6, height=h, thickness=0.15)
    element("IfcWall", storey, rep, _placement(5.0, 0.3, 0, math.pi / 2), "partition")
    column = api.geometry.add_slab_representation(m, context=body, depth=h - 0.5,
                                                  polyline=[(0, 0), (0.3, 0), (0.3, 0.3), (0, 0.3)])
    element("IfcColumn", storey, column, _placement(2.5, 4.0, 0.2), "column")
    table = api.geometry.add_slab_representation(m, context=body, depth=0.75,
                                                 polyline=[(0, 0), (1.5, 0), (1.5, 0.8), (0, 0.8)])
    element("IfcFurniture" if schema != "IFC2X3" else "IfcFurnishingElement", storey, table, _placement(7.0, 5.0, 0), "table")
    room = api.geometry.add_slab_representation(m, context=body, depth=h,
                                                polyline=[(0.3, 0.3), (4.925, 0.3), (4.925, 7.7), (0.3, 7.7)])
    element("IfcSpace", storey, room, _placement(0, 0, 0), "living room")
    if garage:
        block("garage", *GARAGE_AT, GARAGE, slab=0.2, wall=0.2, doors=[(1.0, 2.0, 2.0, "IfcDoor")])
    m.write(str(path))
    return path


def write_mitred_house(path: Path, size=(9.0, 7.0, 3.4), wall: float = 0.3, slab: float = 0.2, gap: float = 0.0) -> Path:
    """A house whose four walls meet in 45-degree mitres (ArchiCAD's FZK-Haus joins its walls so): each wall a
    trapezoid in plan, extruded; a floor slab under them and a roof slab ``gap`` above their tops, all as wide as
    the outline. Its envelope is the box ``size`` (plus ``gap`` in height), from z = -slab."""
    import ifcopenshell.api as api
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.context
    import ifcopenshell.api.geometry
    import ifcopenshell.api.project
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial
    import ifcopenshell.api.unit  # noqa: F401 (each API module is imported by name)

    m = api.project.create_file(version="IFC4")
    body, site = _project(m, api, "mitred")
    building = api.root.create_entity(m, ifc_class="IfcBuilding", name="mitred house")
    api.aggregate.assign_object(m, relating_object=site, products=[building])
    storey = api.root.create_entity(m, ifc_class="IfcBuildingStorey", name="ground floor")
    api.aggregate.assign_object(m, relating_object=building, products=[storey])
    lx, ly, lz = size
    h = lz - 2 * slab

    def extruded(ifc_class, polyline, z, depth):
        e = api.root.create_entity(m, ifc_class=ifc_class, name=ifc_class)
        api.geometry.assign_representation(m, product=e, representation=api.geometry.add_slab_representation(
            m, context=body, depth=depth, polyline=polyline))
        api.geometry.edit_object_placement(m, product=e, matrix=_placement(0, 0, z))
        api.spatial.assign_container(m, relating_structure=storey, products=[e])
        return e

    outer = [(0, 0), (lx, 0), (lx, ly), (0, ly)]
    inner = [(wall, wall), (lx - wall, wall), (lx - wall, ly - wall), (wall, ly - wall)]
    for k in range(4):  # the wall between corners k and k + 1: outer edge, then the inner one back (mitred ends)
        a, b = outer[k], outer[(k + 1) % 4]
        c, d = inner[(k + 1) % 4], inner[k]
        extruded("IfcWall", [a, b, c, d], 0.0, h)
    extruded("IfcSlab", outer, -slab, slab)
    extruded("IfcSlab", outer, h + gap, slab)
    m.write(str(path))
    return path


def write_frame(path: Path, bays: int = 2, span: float = 6.0, height: float = 4.0, section: float = 0.3) -> Path:
    """A steel frame as Tekla exports one: ``bays + 1`` pairs of square columns ``section`` wide and the beams on
    them, in an IfcBuilding, nothing else: (bays + 1) x 2 IfcColumn and bays x 2 + bays + 1 IfcBeam."""
    import ifcopenshell.api as api
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.context
    import ifcopenshell.api.geometry
    import ifcopenshell.api.project
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial  # noqa: F401 (each API module is imported by name)

    m = api.project.create_file(version="IFC2X3")
    import ifcopenshell.api.owner.settings as owner  # IFC2X3: every rooted entity has an owner history

    user = api.owner.add_person_and_organisation(m, person=api.owner.add_person(m),
                                                  organisation=api.owner.add_organisation(m))
    application = api.owner.add_application(m)
    saved = owner.get_user, owner.get_application
    owner.get_user, owner.get_application = (lambda f: user), (lambda f: application)
    try:
        body, site = _project(m, api, "frame")
        building = api.root.create_entity(m, ifc_class="IfcBuilding", name="hall frame")
        api.aggregate.assign_object(m, relating_object=site, products=[building])
        storey = api.root.create_entity(m, ifc_class="IfcBuildingStorey", name="level 0")
        api.aggregate.assign_object(m, relating_object=building, products=[storey])

        def member(ifc_class, x0, y0, z0, x1, y1, z1):
            e = api.root.create_entity(m, ifc_class=ifc_class, name=ifc_class)
            rep = api.geometry.add_slab_representation(m, context=body, depth=z1 - z0,
                                                       polyline=[(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            api.geometry.assign_representation(m, product=e, representation=rep)
            api.geometry.edit_object_placement(m, product=e, matrix=_placement(0, 0, z0))
            api.spatial.assign_container(m, relating_structure=storey, products=[e])

        s = section
        for k in range(bays + 1):
            x = k * span
            for y in (0.0, span):
                member("IfcColumn", x, y, 0.0, x + s, y + s, height)
            member("IfcBeam", x, 0.0, height, x + s, span + s, height + s)  # across, on the pair
        for k in range(bays):
            for y in (0.0, span):
                member("IfcBeam", k * span + s, y, height, (k + 1) * span, y + s, height + s)  # along
        m.write(str(path))
    finally:
        owner.get_user, owner.get_application = saved
    return path


def write_massing(path: Path, blocks=((0.0, 0.0, 20.0, 10.0, 9.0), (20.0, 0.0, 30.0, 6.0, 15.0))) -> Path:
    """A massing model as urban design tools and CityGML converters export one: an IfcBuilding whose elements are
    solid blocks (IfcBuildingElementProxy), ``(x0, y0, x1, y1, height)`` each, standing on the ground side by side;
    no walls, no rooms."""
    import ifcopenshell.api as api
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.context
    import ifcopenshell.api.geometry
    import ifcopenshell.api.project
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial
    import ifcopenshell.api.unit  # noqa: F401 (each API module is imported by name)

    m = api.project.create_file(version="IFC4")
    body, site = _project(m, api, "massing")
    building = api.root.create_entity(m, ifc_class="IfcBuilding", name="block")
    api.aggregate.assign_object(m, relating_object=site, products=[building])
    for k, (x0, y0, x1, y1, height) in enumerate(blocks):
        e = api.root.create_entity(m, ifc_class="IfcBuildingElementProxy", name=f"mass {k}")
        rep = api.geometry.add_slab_representation(m, context=body, depth=height,
                                                   polyline=[(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        api.geometry.assign_representation(m, product=e, representation=rep)
        api.geometry.edit_object_placement(m, product=e, matrix=_placement(0, 0, 0))
        api.spatial.assign_container(m, relating_structure=building, products=[e])
    m.write(str(path))
    return path
