"""What the benchmark runs and at which size: sections, conditions, methods, :class:`BenchConfig` presets."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

__all__ = [
    "SECTIONS", "CORNER_CONDITIONS", "CALIB_CONDITIONS", "OPTICS_CONDITIONS", "FISHEYE_REAL_SETS", "METHODS",
    "CONDITION_PARTS", "SECTION_SEED_OFFSETS", "BenchConfig",
]

SECTIONS: tuple[str, ...] = ("corners", "calibration", "real", "distortion", "speed", "wild", "fisheye", "rig",
                             "markers", "rig_sessions", "video", "hand_eye", "imu", "guidance", "precision",
                             "real_poor", "action_camera")
#: conditions of the corner-accuracy section (paper Table III plus the design's extra ones)
CORNER_CONDITIONS: tuple[str, ...] = ("clean", "blur_noise", "bad_lighting", "mild", "severe", "combined")
#: conditions of the synthetic calibration section (paper Table I, then realistic optics)
CALIB_CONDITIONS: tuple[str, ...] = ("blur_noise", "bad_lighting", "level1", "level2", "optics", "optics_blur_noise")
#: detection methods: key -> label used in the reports
METHODS: dict[str, str] = {
    "learned": "ccs_kornia learned",
    "opencv_saddle": "opencv+saddle",
    "opencv_subpix": "cv2 classic+cornerSubPix",
    "opencv_sb": "cv2 findChessboardCornersSB",
    "libcbdetect": "libcbdetect",
}
#: condition name -> (photometric condition of ``augment.CONDITIONS``, radial level or None)
CONDITION_PARTS: dict[str, tuple[str, str | None]] = {
    "clean": ("clean", None),
    "blur_noise": ("blur_noise", None),
    "noise": ("blur_noise", None),
    "bad_lighting": ("bad_lighting", None),
    "combined": ("combined", None),
    "mild": ("clean", "level1"),
    "level1": ("clean", "level1"),
    "level2": ("clean", "level2"),
    "severe": ("clean", "severe"),
    "optics": ("clean", None),
    "optics_blur_noise": ("blur_noise", None),
}
#: conditions finished by a camera's last mile, as every ``wild`` render is (``data.render.optics.apply_optics``: a 0.3-1 px
#: Gaussian point spread, read and shot noise, a tone curve of gamma 1.8-2.4: the plain renders are kinder to our
#: detector than real optics)
OPTICS_CONDITIONS: tuple[str, ...] = ("optics", "optics_blur_noise")
#: the real sets with fisheye lenses (section 7 calibrates them with a fisheye model; section 3 leaves them out)
FISHEYE_REAL_SETS: tuple[str, ...] = ("ros_fisheye_mono", "boofcv_fisheye_chessboard")
#: seed offsets of the sections, so no two sections render the same scene
SECTION_SEED_OFFSETS = {"corners": 0, "calibration": 100_000, "distortion": 200_000, "speed": 300_000, "wild": 400_000}


@dataclass
class BenchConfig:
    """What the benchmark runs and at which size (see :meth:`full`, :meth:`quick`, :meth:`tiny`).

    Attributes:
        sections: sections to run, a subset of :data:`SECTIONS`.
        methods: detection methods, a subset of :data:`METHODS` (unavailable ones are reported and skipped).
        image_size: ``(W, H)`` of the synthetic images.
        board: ``(cols, rows)`` inner corners of the synthetic board.
        square: square side (m) of the synthetic board.
        supersample: renderer sub-cells per pixel side.
        corner_conditions: conditions of the corner section.
        corner_images: images per condition (corner section).
        corner_views_per_camera: views per random camera in the corner section.
        corner_ablations: extra rows of the corner section, keys of
            :data:`~ccs_kornia.bench.methods.methods.ABLATIONS` (run when their base method is among ``methods``; not
            counted in *mean common*).
        error_threshold: a corner further than this (px) from the truth is wrong.
        calib_conditions: conditions of the calibration section.
        calib_trials: calibration trials per condition.
        calib_views: views per trial.
        calib_pool_views: views rendered per camera; trials of one camera draw ``calib_views`` of them
            (``calib_pool_views == calib_views`` gives fully independent trials).
        calib_trials_per_camera: trials drawn from one camera's pool.
        calib_methods: detection methods of the calibration section (``None``: all of ``methods``).
        real_dir: folder of the real photograph sets (``None``: ``../shared/data/real`` beside the repo).
        real_sets: set names to run (``None``: every known set found).
        real_subsets: random view subsets per set.
        real_subset_fraction: fraction of a set's images in one subset.
        real_max_images: at most this many images per set (``None``: all).
        dc_trials, dc_views: trials (cameras) and views of the severe-distortion part of the distortion section.
        wide_trials, wide_views, wide_size, wide_fx: the paper's wide camera (level-2 distortion) part.
        distortion_weights: DistortionNet export (``None``: the shipped weights).
        speed_batch_sizes: detection batch sizes timed.
        speed_images: images timed per batch size.
        speed_solver_cameras: camera counts of the batched solver timing.
        speed_repeats: repeats of each timing (best is kept).
        speed_real_set: real set timed end to end with ``python -m ccs_kornia calibrate`` (``None``: not run).
        devices: ``cpu`` and/or ``cuda`` (``cuda`` skipped when not present).
        learned_batch: images per learned-detector call.
        wild_methods: detection methods of the ``wild`` section (``None``: all of ``methods``); by default the
            usual peers (OpenCV classic + cornerSubPix, SB, libcbdetect) and ours.
        wild_time_limit: seconds a peer may spend on one image of the wild section (then: no board, "timed out").
        wild_conditions: conditions of the ``wild`` section (``None``: all of ``bench.sections.wild.WILD_CONDITIONS``).
        wild_images: images per wild condition; wild_big_images: per condition of 4 Mpx and more.
        wild_free_images: board-free images of the wild section.
        wild_real_sets: real sets rescaled in the wild section (``None``: all eight).
        fisheye_trials, fisheye_views, fisheye_noise, fisheye_fov, fisheye_fail_px: the synthetic part of the
            ``fisheye`` section (cameras, views each, corner noise px, field of view range in degrees, E_IP above
            which a calibration counts as failed); fisheye_rendered: also render those cameras' views and let every
            method detect its own corners (:mod:`~ccs_kornia.bench.sections.fisheye_rendered`); fisheye_real_sets: its
            real sets.
        wild_real_scales: rescaling factors of the real photos; wild_real_images: images per set (``None``: all).
        rig_trials, rig_frames: rendered rigs of the ``rig`` section and frames per rig (:mod:`~ccs_kornia.bench.sections.rig`).
        rig_session_trials, rig_session_duration, rig_session_conditions, rig_session_caliscope: the
            ``rig_sessions`` section (:mod:`~ccs_kornia.bench.sections.rig_sessions`): rendered hand-held sessions, seconds
            each, their conditions, and whether the shared caliscope session runs too.
        markers_views, markers_aprilgrid_views: rendered ChArUco / AprilGrid views per condition of the ``markers``
            section (:mod:`~ccs_kornia.bench.sections.markers`); markers_calib_trials, markers_calib_views: its calibrations
            from partial views; markers_real_sets: its real ChArUco sets.
        video_recordings, video_seconds, video_size: the ``video`` section's rendered recordings (how many, seconds
            at 30 fps, ``(W, H)``; :mod:`~ccs_kornia.bench.sections.video`); video_heldout_seconds, video_heldout_frames: the
            held-out recording of each camera and the frames of it detected; video_command: also time ``calibrate
            VIDEO`` end to end; video_jobs: processes; video_real_cameras, video_real_rig: the cameras of the shared
            caliscope recording compared one by one, and whether its rig is.
        hand_eye_trials: rendered robots per set-up of the ``hand_eye`` section (:mod:`~ccs_kornia.bench.sections.hand_eye`);
            hand_eye_views: the range of their poses; hand_eye_kinematic_trials: rendered arms with kinematic errors per
            set-up; hand_eye_real: also its real robots (where the data is found).
        real_poor_images, real_poor_sets, real_poor_conditions: the ``real_poor`` section
            (:mod:`~ccs_kornia.bench.sections.real_poor`): images per set (per camera of a multi-camera set), the sets
            (``None``: every ChArUco and chessboard set known) and the conditions
            (:data:`~ccs_kornia.data.render.poor_images.POOR_CONDITIONS`).
        action_camera_views: rendered views of the ``action_camera`` section
            (:mod:`~ccs_kornia.bench.sections.action_camera`), each under ``real_poor_conditions`` too.
        imu_trials, imu_seconds, imu_conditions: the ``imu`` section's rendered recordings per condition, their length
            (s) and the conditions (:data:`~ccs_kornia.bench.sections.imu.CONDITIONS`).
        guidance_trials, guidance_cameras, guidance_counts: the ``guidance`` section's simulated people per camera kind,
            the kinds (:data:`~ccs_kornia.bench.sections.guidance.CAMERAS`) and the frame counts compared
            (:data:`~ccs_kornia.bench.sections.guidance.COUNTS`).
        precision_models: the camera models of the ``precision`` section (:mod:`~ccs_kornia.bench.sections.precision`:
            mrcal's published corners; ``()``: the set read, nothing solved).
    """

    sections: tuple[str, ...] = SECTIONS
    methods: tuple[str, ...] = tuple(METHODS)
    image_size: tuple[int, int] = (640, 480)
    board: tuple[int, int] = (9, 6)
    square: float = 0.025
    supersample: int = 3
    corner_conditions: tuple[str, ...] = CORNER_CONDITIONS
    corner_images: int = 60
    corner_views_per_camera: int = 15
    corner_ablations: tuple[str, ...] = ("learned_collinearity", "learned_collinearity_last")
    error_threshold: float = 3.0
    calib_conditions: tuple[str, ...] = CALIB_CONDITIONS
    calib_trials: int = 50
    calib_views: int = 15
    calib_pool_views: int = 30
    calib_trials_per_camera: int = 5
    calib_methods: tuple[str, ...] | None = None
    real_dir: str | None = None
    real_sets: tuple[str, ...] | None = None
    real_subsets: int = 20
    real_subset_fraction: float = 0.7
    real_max_images: int | None = None
    dc_trials: int = 20
    dc_views: int = 15
    wide_trials: int = 20
    wide_views: int = 15
    wide_size: tuple[int, int] = (480, 480)
    wide_fx: tuple[float, float] = (100.0, 300.0)
    distortion_weights: str | None = None
    speed_batch_sizes: tuple[int, ...] = (1, 16)
    speed_images: int = 16
    speed_solver_cameras: tuple[int, ...] = (1, 16, 64)
    speed_repeats: int = 2
    speed_real_set: str | None = "udacity_gopro_wide"
    devices: tuple[str, ...] = ("cpu", "cuda")
    learned_batch: int = 8
    wild_methods: tuple[str, ...] | None = ("learned", "opencv_subpix", "opencv_sb", "libcbdetect")
    wild_time_limit: float | None = 300.0
    wild_conditions: tuple[str, ...] | None = None
    wild_images: int = 20
    wild_big_images: int = 5
    wild_free_images: int = 200
    wild_real_sets: tuple[str, ...] | None = None
    wild_real_scales: tuple[float, ...] = (0.5, 1.5, 2.0, 4.0)
    wild_real_images: int | None = 6
    fisheye_trials: int = 50
    fisheye_views: int = 15
    fisheye_noise: float = 0.1
    fisheye_fov: tuple[float, float] = (120.0, 200.0)
    fisheye_fail_px: float = 20.0
    fisheye_rendered: bool = True
    fisheye_real_sets: tuple[str, ...] = FISHEYE_REAL_SETS
    rig_trials: int = 30
    rig_frames: int = 20
    rig_session_trials: int = 8
    rig_session_duration: float = 40.0
    rig_session_conditions: tuple[str, ...] = ("handheld", "global", "timestamps", "frozen")
    rig_session_caliscope: bool = True
    markers_views: int = 120
    markers_aprilgrid_views: int = 40
    markers_calib_trials: int = 5
    markers_calib_views: int = 12
    markers_real_sets: tuple[str, ...] = ("charuco_opencv_tutorial", "caliscope_4cam_charuco")
    video_recordings: int = 5
    video_seconds: float = 60.0
    video_size: tuple[int, int] = (1280, 720)
    video_heldout_seconds: float = 30.0
    video_heldout_frames: int = 60
    video_command: bool = True
    video_jobs: int = 2
    video_real_cameras: tuple[int, ...] = (0, 1, 2, 3)
    video_real_rig: bool = True
    hand_eye_trials: int = 20
    hand_eye_views: tuple[int, int] = (8, 30)
    hand_eye_kinematic_trials: int = 6
    hand_eye_real: bool = True
    real_poor_images: int = 12
    real_poor_sets: tuple[str, ...] | None = None
    real_poor_conditions: tuple[str, ...] = ("dark", "dark sensor", "blur", "motion", "small", "jpeg")
    action_camera_views: int = 16
    imu_trials: int = 10
    imu_seconds: float = 60.0
    imu_conditions: tuple[str, ...] = ("given", "noise x10", "noise /10", "stereo", "rolling shutter", "stereo, rig held",
                                       "IMU errors, ideal model", "IMU errors, scale-misalignment", "given, sag judged",
                                       "bent board, flat", "bent board, sag judged")
    guidance_trials: int = 8
    guidance_cameras: tuple[str, ...] = ("normal", "wide", "fisheye")
    guidance_counts: tuple[int, ...] = (4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40)
    preset: str = "full"
    precision_models: tuple[str, ...] = ("rational", "fisheye", "splined")
    extra: dict = field(default_factory=dict)

    @classmethod
    def full(cls, **overrides) -> BenchConfig:
        """The full run (target: under 60 minutes on 2 CPU cores; the camera-IMU section about 15 of them)."""
        return replace(cls(), **overrides)

    @classmethod
    def quick(cls, **overrides) -> BenchConfig:
        """A smoke run of every section: one or two images, trials or sets per condition, short peer time limits
        (target: under 150 s on 2 idle CPU cores)."""
        base = cls(
            corner_images=4, corner_views_per_camera=4, calib_trials=2, calib_views=6, calib_pool_views=6,
            calib_trials_per_camera=1, real_subsets=3, real_max_images=8, dc_trials=2, dc_views=6, wide_trials=1,
            wide_views=6, speed_images=4, speed_solver_cameras=(1, 16), speed_repeats=1,
            speed_real_set="boofcv_bumblebee2_left", supersample=2, preset="quick",
            real_sets=("opencv_left", "boofcv_bumblebee2_left"),
            calib_methods=("learned", "opencv_saddle", "opencv_subpix", "opencv_sb"),
            wild_images=1, wild_big_images=1, wild_free_images=2, wild_real_sets=("opencv_left",),
            wild_real_scales=(0.5, 2.0), wild_real_images=1, wild_time_limit=1.0,
            fisheye_trials=2, fisheye_views=6, fisheye_real_sets=("ros_fisheye_mono",), rig_trials=2,
            rig_session_trials=1, rig_session_conditions=("handheld",), rig_session_caliscope=False,
            markers_views=2, markers_aprilgrid_views=1, markers_calib_trials=1, markers_calib_views=8,
            markers_real_sets=("charuco_opencv_tutorial",), hand_eye_trials=1, hand_eye_kinematic_trials=1,
            imu_trials=1, imu_seconds=10.0, imu_conditions=("given",), precision_models=("rational",),
            guidance_trials=2, guidance_cameras=("normal",),
            real_poor_images=2, real_poor_sets=("charuco_opencv_tutorial", "caliscope_4cam_charuco", "opencv_left"),
            action_camera_views=1,
            video_recordings=1, video_seconds=8.0, video_size=(640, 360), video_heldout_seconds=6.0,
            video_heldout_frames=8, video_real_cameras=(0,), video_real_rig=False,
        )
        return replace(base, **overrides)

    @classmethod
    def tiny(cls, **overrides) -> BenchConfig:
        """The smallest configuration that still exercises every section (used by the tests)."""
        base = cls(
            image_size=(320, 240), board=(6, 4), supersample=1, corner_conditions=("clean", "severe"),
            corner_images=2, corner_views_per_camera=2, calib_conditions=("blur_noise",), calib_trials=2,
            calib_views=5, calib_pool_views=5, calib_trials_per_camera=1, real_subsets=2, real_max_images=6,
            dc_trials=1, dc_views=5, wide_trials=1, wide_views=5, wide_size=(240, 240), wide_fx=(60.0, 150.0),
            speed_batch_sizes=(1, 2), speed_images=2, speed_solver_cameras=(1, 2), speed_repeats=1, speed_real_set=None,
            real_sets=("boofcv_bumblebee2_left",), calib_methods=("opencv_saddle", "opencv_subpix"),
            wild_methods=None, wild_conditions=("img320", "cut"), wild_images=1, wild_big_images=1, wild_free_images=2,
            wild_real_sets=("boofcv_bumblebee2_left",), wild_real_scales=(0.5,), wild_real_images=1,
            fisheye_trials=2, fisheye_views=6, fisheye_real_sets=(), rig_trials=1, rig_frames=10, preset="tiny",
            rig_session_trials=1, rig_session_duration=8.0, rig_session_conditions=("handheld",),
            rig_session_caliscope=False,
            markers_views=1, markers_aprilgrid_views=1, markers_calib_trials=1, markers_calib_views=8,
            markers_real_sets=(), hand_eye_trials=1, hand_eye_views=(8, 8), hand_eye_real=False,
            hand_eye_kinematic_trials=0,
            imu_trials=1, imu_seconds=6.0, imu_conditions=("given",), precision_models=(),
            guidance_trials=1, guidance_cameras=("normal",), guidance_counts=(4, 6, 8),
            real_poor_images=1, real_poor_sets=("charuco_opencv_tutorial", "boofcv_bumblebee2_left"),
            real_poor_conditions=("dark", "small"), action_camera_views=1,
            video_recordings=1, video_seconds=2.0, video_size=(320, 240),
            video_heldout_seconds=2.0, video_heldout_frames=4, video_command=False, video_real_cameras=(),
            video_real_rig=False,
        )
        return replace(base, **overrides)

    def to_dict(self) -> dict:
        return asdict(self)
