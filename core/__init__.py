"""The SLAM itself: pure numpy (and OpenCV for features), no file or terminal I/O."""
