"""The built-in landmark sources: files of 3D points (TRC, CSV), 2D keypoints triangulated in the
session's cameras (OpenPose JSON), and a synthetic capture's joints."""
