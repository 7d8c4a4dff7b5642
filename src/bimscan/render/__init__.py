"""Pictures of clouds and models (paper Fig. 3).

``cloud`` (top and oblique views of any cloud file), ``figure`` (model, synthetic and real scan
side by side), ``mesh`` (flat-shaded BIM meshes), ``raster`` (z-buffered Numba kernels),
``view`` (cameras and storey sections), ``compose`` (exact-size PNGs with titles and legends).
"""
