"""Knobs of the geometry layer, each with its reason."""

#: Points on each collision shape for the spheres are at most this far apart (m): a mesh's
#: triangles are filled to this spacing, so that the spheres cover the surface between its
#: vertices, not only the vertices.
SURFACE_SPACING = 0.01

#: A link's spheres are added one at a time until the worst gap (how far a sphere's surface
#: stands off the link's geometry) is at most this (m)...
GAP_TARGET = 0.02

#: ...or until the link has this many (each sphere is a row per sample and obstacle in the
#: bounded solve).
MAX_SPHERES = 6

#: Lloyd iterations of the k-means that groups a link's surface points, and iterations of
#: the Badoiu-Clarkson walk that shrinks each group's enclosing sphere: a fixed amount of
#: work, so that the same URDF gives the same spheres on any machine load.
KMEANS_ITERATIONS = 30
ENCLOSING_ITERATIONS = 200

#: The k-means runs on every k-th surface point, about this many (then every point joins
#: its nearest group): the groups' shapes need no more.
KMEANS_POINTS = 2000

#: Points per sphere where its gap is measured.
GAP_PROBES = 200

#: The collision margin's default (m): the clearance every published motion keeps.
DEFAULT_MARGIN = 0.01
