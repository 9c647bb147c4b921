"""Line-of-sight corrections: atmospheric refraction, light-time and aberration of light (issue 44)."""
