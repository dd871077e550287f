"""``hybrid validate``: check a scene file and report every problem."""
import sys

from hybrid.app import geometry

from .parse import SceneError, load_scene


def validate_command(path, check=None):
    """``hybrid validate <path>``: print "OK: ..." (stdout) or every problem (stderr); return 0 or 2.

    ``check(scene)``, when given, runs on a scene that parsed and raises ValueError (or
    SceneError) for problems only the built bodies show (an anchor box holding no node, say): what
    ``hybrid run`` would reject, ``validate`` rejects too; it returns the warnings a run would give
    (bodies overlapping or inside a plane, say), printed as ``hybrid run`` prints them."""
    try:
        scene = load_scene(path)
        deformable = sum(b.model != "rigid" for b in scene.bodies)
        if check is not None and deformable:    # (a 50k-tet body took 22 s with nothing said)
            print(f"{path}: checking the built bodies: meshing and factorising {deformable} "
                  f"deformable bod{'y' if deformable == 1 else 'ies'}", file=sys.stderr, flush=True)
        if check is not None:
            try:
                with geometry.caught_mesh_warnings() as repaired:
                    said = check(scene) or []
            except (ValueError, geometry.MeshError) as error:
                raise SceneError([f"{path}: {error}"]) from None
            for message in [*repaired, *said]:
                print(f"warning: {message}", file=sys.stderr)
    except SceneError as error:
        for problem in error.problems:
            print(problem, file=sys.stderr)
        print(f"{path}: {len(error.problems)} problem{'s' if len(error.problems) != 1 else ''}",
              file=sys.stderr)
        return 2
    print(f"OK: {path}: {len(scene.bodies)} bodies, {len(scene.planes)} planes")
    return 0
