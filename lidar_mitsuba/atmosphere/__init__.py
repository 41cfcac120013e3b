"""The air between the lidar and the ground beyond the clear-sky link budget: clouds
(:mod:`.cloud_layer`: the layer as an input and its closed forms; :mod:`.cloud_kernel`: its
forward-scattered light tabulated once from the media integrator and applied to any run's
returns). Pure numpy at import; the kernel's tabulation sets the renderer up when it runs.
"""
from .cloud_layer import Cloud, CloudClimatology  # noqa: F401
