"""The operator's 3D map (viser): the scene, one panel per browser, click geometry."""
