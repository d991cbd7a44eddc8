"""The napari plugin of lfm_studio (manifest: ``lfm_studio/napari.yaml``).

Readers and a writer for our TIFFs and design files, the bead sample data, and three
dock widgets (Simulate PSF, Reconstruct light field, MLA editor). Qt is imported
through ``qtpy`` only, so the plugin runs under whichever binding napari uses.
Nothing is imported here: napari loads each contribution's module on demand.

Layer conventions (:mod:`lfm_studio.napari_plugin.layer_data`): scales are micrometres;
light-field images and PSF stacks share the *sensor* pixel pitch (so a PSF lies on the
camera image it explains), volumes use object-space voxels; the depth axis of PSF
stacks and volumes is the sample-side depth, translated so napari's z coordinate reads
the depth itself.
"""
