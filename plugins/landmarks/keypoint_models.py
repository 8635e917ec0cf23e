"""The keypoint orders of the body detectors whose output the 2D sources read without names in the file
(FreeMoCap's arrays, Caliscope's keypoint ids), each as its own library or model card numbers them. OpenPose's
orders are in :mod:`.openpose`; the sources rename these to OpenPose's names where OpenPose has the joint
(:func:`mmcsplat.scene.human_skeleton.openpose_name`)."""

from __future__ import annotations

#: MediaPipe Pose's 33 landmarks (its ``PoseLandmark`` enumeration).
MEDIAPIPE_BODY = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer", "left_ear", "right_ear",
    "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_pinky", "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee",
    "right_knee", "left_ankle", "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
#: COCO's 17 body keypoints: YOLO's pose model, and the first 17 of Halpe's and of COCO-WholeBody's.
COCO = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
        "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle")
#: Halpe's 26 (RTMPose's ``halpe26`` models): COCO's, then the head, neck and mid-hips, then the feet.
HALPE26 = (*COCO, "head", "neck", "hip", "left_big_toe", "right_big_toe", "left_small_toe", "right_small_toe", "left_heel", "right_heel")
#: COCO-WholeBody's body and feet (its first 23 of 133; the face and hands follow).
COCO_WHOLEBODY_BODY = (*COCO, "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe", "right_heel")
