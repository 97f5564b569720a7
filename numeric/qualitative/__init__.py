"""Qualitative navigation (Morizane, Yamada, Toyoda): observations -> relations -> DRM."""
