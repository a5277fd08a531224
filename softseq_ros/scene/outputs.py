"""The outputs a scene may list (``outputs:``): what the rig computes and publishes for it."""

OUTPUT_NAMES = ('pressure', 'volumes', 'curvature', 'poses', 'markers', 'image', 'events')
# Images are the heaviest output, so a scene asks for them explicitly.
DEFAULT_OUTPUTS = frozenset(name for name in OUTPUT_NAMES if name != 'image')
