"""``hybrid validate``: check a scene file and report every problem."""
import sys

from hybrid.app import geometry

from .parse import SceneError, load_scene


def validate_command(path, check=None):
    """``hybrid validate <path>``: print "OK: ..." (stdout) or every problem (stderr); return 0 or 2.

    ``check(scene)``, when given, runs on a scene that parsed and raises ValueError for problems
    only the built bodies show (an anchor box holding no node, say): what ``hybrid run`` would
    reject, ``validate`` rejects too."""
    try:
        scene = load_scene(path)
        if check is not None:
            try:
                with geometry.caught_mesh_warnings() as repaired:
                    check(scene)
            except (ValueError, geometry.MeshError) as error:
                raise SceneError([f"{path}: {error}"]) from None
            for message in repaired:
                print(f"warning: {message}", file=sys.stderr)
    except SceneError as error:
        for problem in error.problems:
            print(problem, file=sys.stderr)
        print(f"{path}: {len(error.problems)} problem{'s' if len(error.problems) != 1 else ''}",
              file=sys.stderr)
        return 2
    print(f"OK: {path}: {len(scene.bodies)} bodies, {len(scene.planes)} planes")
    return 0
