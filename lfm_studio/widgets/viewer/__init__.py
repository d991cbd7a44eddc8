"""Volume and image display: the embedded napari viewer (:mod:`.napari_embed`, :mod:`.napari_scene`),
the pyqtgraph fallback (:mod:`.pyqtgraph_volume`) and the display data they share (:mod:`.display_data`)."""
