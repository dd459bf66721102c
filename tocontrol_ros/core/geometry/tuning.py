"""Knobs of the geometry layer, each with its reason."""

#: Points on each collision shape for the spheres are at most this far apart (m): a mesh's
#: triangles are filled to this spacing, so that the spheres cover the surface between its
#: vertices, not only the vertices.
SURFACE_SPACING = 0.01

#: Each sphere's radius reaches this far beyond its farthest surface point (m): a point of
#: the surface is within SURFACE_SPACING / sqrt(2) of one of the points (a triangle filled
#: to that spacing, a primitive's grid), so the spheres cover the whole surface.
COVER_PAD = 0.75 * SURFACE_SPACING

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

#: The certificate measures the exact distances at this many equally spaced times of a
#: motion; between two of them a distance can fall by at most its speed bound times half the
#: step (CollisionModel.swept), so the finer the step the less margin that bound eats.
CERTIFY_STEPS = 1000

#: Where that bound falls below the margin on an interval, the interval is halved up to this
#: many times (Coal's exact distances at the new times, the motion's speed bound on each
#: part): the fall halves each time, and a motion that keeps the margin by more than the
#: last fall passes (a fixed amount of work, the same verdict on any load)...
CERTIFY_BISECTIONS = 5

#: ...on at most this many intervals of a motion (the first ones; the others keep their
#: bound).
CERTIFY_REFINED = 400

#: Where a bounding sphere's distance (a lower bound) is more than this above what must
#: hold, Coal is not asked for the exact distance (m): the bound already certifies it.
EXACT_BAND = 0.02
