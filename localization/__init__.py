"""Localization from BIM structural landmarks: detect, associate, PnP, ArUco baseline, metrics.

Pure numpy / scipy / OpenCV; usable on images and poses that did not come from the simulator.
"""
