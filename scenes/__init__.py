"""Scene files shipped with SCET (installed as the data package ``scet_scenes``)."""
