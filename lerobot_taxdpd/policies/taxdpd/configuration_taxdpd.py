"""Configuration of the TAX-DPD goal predictor (`--policy.type=taxdpd`).

Units: the model works in "model units", metres times `point_scale`. `point_scale` is chosen once, from the
training data, so that the median object radius equals `object_scale` (the paper's dataset scaling); it is
stored in config.json so a checkpoint always rescales inputs exactly as it was trained. Lengths below that
say "model units" are in that space (object radius ~ `object_scale`).

Ablation switches (each row of the paper's ablation tables):
    disentangled=false                  w/o disentangled point diffusion
    encoder=mlp                         w/ MLP encodings
    use_gmm=false                       w/o GMM (diffuse from the scene centroid)
    use_reconstruction_embedding=false  w/o reconstruction embedding
    use_rotation_noise=false            w/o rotation noise
    use_deformation_embedding=false     w/o deformation embedding
    local_diffusion=se3                 w/ SE(3) diffusion (6-D rotation + translation DDPM)
A TAX3D-style baseline (one point diffusion in the scene frame, separate object/scene encoders) is
use_gmm=false disentangled=false use_reconstruction_embedding=false use_deformation_embedding=false.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.optim.schedulers import DiffuserSchedulerConfig

from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.policies.optim import FusedAdamWConfig

ENCODERS = ("pointnet2", "mlp")
LOCAL_DIFFUSIONS = ("point", "se3")
SAMPLERS = ("ddim", "ddpm")
PREDICTION_TYPES = ("epsilon", "sample", "v_prediction")
COMPILE_MODES = (None, "default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
ROTATION_NOISES = ("paper", "signal")
GMM_FRAMES = ("components", "modes")
#: Beyond 12 octaves the shortest period (12.6 / 2^11 model units) is below any sensor's noise.
MAX_POSITION_OCTAVES = 12


def check_frame_temperature(frame_temperature: float, disentangled: bool) -> None:
    """A clear error for a frame temperature that is not a finite number >= 0, or for one other than 1 on a
    model without a frame to scale."""
    if isinstance(frame_temperature, bool) or not isinstance(frame_temperature, numbers.Real):
        raise ValueError(f"frame_temperature: must be a number >= 0, got {frame_temperature!r}")
    if not (math.isfinite(frame_temperature) and frame_temperature >= 0):
        raise ValueError(f"frame_temperature: must be a finite number >= 0, got {frame_temperature!r}")
    if frame_temperature != 1.0 and not disentangled:
        raise ValueError("frame_temperature: needs disentangled=true (the joint diffusion has no frame of its own)")


def check_inference_steps(num_inference_steps: int, num_train_timesteps: int) -> None:
    """Sampling steps must divide the training steps: diffusers' DDIM steps from t to t - T // n, so any other
    count would pair timesteps inexactly and skip part of the schedule."""
    valid = [n for n in range(1, num_train_timesteps + 1) if num_train_timesteps % n == 0]
    if not isinstance(num_inference_steps, int) or num_inference_steps not in valid:
        raise ValueError(
            f"num_inference_steps: must divide num_train_timesteps={num_train_timesteps} (one of {valid}), "
            f"got {num_inference_steps!r}"
        )


@PreTrainedConfig.register_subclass("taxdpd")
@dataclass
class TaxDPDConfig(PreTrainedConfig):
    # ---- inputs / outputs
    n_obs_steps: int = 1
    # Points the network sees. Larger clouds are reduced by farthest point sampling: in training with the same
    # indices for object and goal (correspondence survives), at inference deterministically, with the
    # predicted motion lifted back to every input point (exact for rigid placements).
    num_object_points: int = 512
    num_scene_points: int = 1024
    # Point clouds must keep one isotropic scale and one origin: never normalise them per axis.
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    # ---- dataset scaling
    object_scale: float = 3.0
    point_scale: float | None = None  # model units per metre; derived from the training data when unset

    # ---- architecture (paper: DiT depth 5, hidden 128, 4 heads; same size for both stages)
    hidden_dim: int = 128
    num_blocks: int = 5
    num_heads: int = 4
    mlp_ratio: float = 4.0
    timestep_embed_dim: int = 256
    encoder: str = "pointnet2"
    # PointNet++: centroid ratios of the two set-abstraction levels and their ball radii (model units).
    sa_ratios: tuple[float, float] = (0.2, 0.25)
    sa_radii: tuple[float, float] = (1.5, 3.0)
    max_neighbors: int = 64

    # ---- ablation switches (see module docstring)
    use_gmm: bool = True
    disentangled: bool = True
    use_reconstruction_embedding: bool = True
    use_deformation_embedding: bool = True
    use_rotation_noise: bool = True
    local_diffusion: str = "point"

    # ---- global stage: Dense GMM
    gmm_variance: float = 0.3  # fixed component variance (model units^2)
    gmm_uniform_weight: float = 0.1  # weight of the NLL under uniform mixing weights (keeps components useful)
    gmm_batch_fraction: float = 1.0  # share of each batch the Dense GMM trains on (it converges early)
    # Where a sample's placement frame comes from: "components", the mean of a component drawn by its weight
    # (as published); "modes", that mean moved uphill to the peak of the mixture's density it lies under
    # (mean shift at the components' own width), so that the frames of the components that share a slot
    # agree on its most likely point instead of scattering around it. Sampling only: training is the same.
    gmm_frames: str = "components"

    # ---- local stage: disentangled DDPM
    num_train_timesteps: int = 100
    beta_start: float = 1e-4  # given for a 1000-step schedule and rescaled to num_train_timesteps
    beta_end: float = 0.02
    # What the denoiser outputs: the clean goal ("sample"), the noise ("epsilon", the paper's) or v. The noise
    # target hardly weighs orientation where it is decided (docs/taxdpd.md, "Learning orientation").
    prediction_type: str = "sample"
    rotation_noise_std_deg: float = 45.0
    # "signal": the clean shape itself is turned inside the noisy sample, by an angle whose std shrinks with
    # the remaining signal (needs prediction_type='sample'; the target stays the unturned goal); "paper":
    # R phi - phi added to the shape's noise, as published, which leaves a copy of the shape at the last step.
    rotation_noise: str = "signal"
    # A pose-level term beside the point losses (0: the paper's loss): the squared angle (radians) of the rigid
    # turn between the predicted and the true clean goal shapes, times this weight. The point MSE weighs a
    # 1 deg turn far below the scatter of the points; this term weighs the turn alone (needs the clean target).
    # Measured on the book (docs/taxdpd.md): at 30 it halved the turn and moved the position, and flattened the
    # samples across the book's thickness, where a squashed cloud hides a turn.
    rotation_loss_weight: float = 0.0
    # A shape-level term beside it (0: the paper's loss): the predicted clean goal shape's spread along each of
    # its principal axes against the true shape's (relative, squared), weighted like the pose-level term. It
    # charges the squashing that the pose-level term alone rewards across a thin axis. Measured on the book at 3
    # beside a pose-level weight of 30 (docs/taxdpd.md): the executed pose got worse (8.7 deg), so it stays off.
    spread_loss_weight: float = 0.0
    # The frame's (goal centroid's) loss against the shape's, 1 as published (half each). The shape's loss holds
    # the scatter of every point and dwarfs the frame's where the object is large (a book: 6x), so the shared
    # network spends little on reading where in the scene the centroid goes.
    frame_loss_weight: float = 1.0
    frame_noise_std: float = 1.0  # training frames g = goal centroid + N(0, std^2) (model units)
    # Where the frame's denoised value is read: False, as published, from the frame token alone; True, the frame
    # token's output plus the mean of the point head's outputs, which the shape's centring discards otherwise, so
    # that every object token votes where its own point goes from the scene around it (the book's frame token
    # does not find its slot along the shelf's row: docs/taxdpd.md, "Where the local stage puts the book").
    frame_from_points: bool = False
    # What the local stage sees of the scene: 0, the scene the network sees (num_scene_points of it, the paper's
    # layout); N > 0, the N points of the scene as given (denser than num_scene_points when the dataset records
    # more) nearest the placement frame, so the place the object goes is seen at the recorded density whatever
    # the scene's extent (RPDiff crops its scene likewise).
    local_scene_points: int = 0
    # With local_scene_points: the local stage also sees the scene the network sees, its own set of tokens
    # beside the crop's, so what only the whole scene shows (a shelf's row of books, which way its slots run)
    # is not cropped away with the distant points.
    local_scene_with_whole: bool = False
    # Fourier features of every local-stage token's position (the goal estimate's points, the scene's), sines and
    # cosines at this many octave frequencies from 0.5 per model unit, added through a linear layer that starts at
    # zero; 0, as published, leaves positions to the encoders' linear layers, which learn fine position slowly.
    position_octaves: int = 0
    sampler: str = "ddim"
    num_inference_steps: int = 10
    # The scale of the placement frame's starting noise when sampling (the shape's keeps the full scale): 1 as
    # published; below 1 starts each sample's frame nearer its GMM frame, low-temperature sampling that trades
    # the frames' spread around a slot for their precision. Sampling only: training is the same.
    frame_temperature: float = 1.0
    num_goal_samples: int = 1  # goals sampled per call of `select_action` (the first is returned)

    # ---- training augmentation
    # Object, scene and goal turned together about the vertical by U(+-z_rotation_range) degrees: 180 is the
    # paper's whole circle; a task whose scenes keep a rough heading in the robot's frame (a board facing the
    # robot) learns its fine orientation faster from a range that only covers that variation.
    z_rotation_augmentation: bool = True
    z_rotation_range: float = 180.0
    # The object alone turned about its centroid by a random yaw in +-start_yaw_range and a tilt about a
    # random horizontal axis up to start_tilt_range (degrees), the goal kept: the start orientation then says
    # nothing about the goal's, so the network must read it off the object's shape and the scene.
    start_yaw_range: float = 180.0
    start_tilt_range: float = 0.0
    object_occlusion_prob: float = 0.0  # random plane cut of the object (the authors used 0.8)
    scene_occlusion_prob: float = 0.0  # random ball cut of the scene (the authors used 0.8)

    # ---- pose estimation
    ransac_threshold: float | None = None  # metres; default 5 percent of the object's RMS radius
    ransac_hypotheses: int = 256

    # ---- exponential moving average of the weights, sampled from when on (DP3's warm-up decay)
    use_ema: bool = False
    ema_power: float = 0.75
    ema_max_decay: float = 0.9999

    # ---- speed: torch.compile of the DiTs (None: eager; the point encoders stay eager, see compile_networks).
    # "default" uses inductor on the CPU; on a GPU "reduce-overhead" adds CUDA graphs. The weights' names do not
    # change, so checkpoints load either way.
    compile_mode: str | None = None

    # ---- optimisation (paper: AdamW 1e-4, wd 1e-5, warmup 100, cosine, clip 1.0)
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-5
    optimizer_grad_clip_norm: float = 1.0
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 100

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder: must be one of {ENCODERS}, got {self.encoder!r}")
        if self.compile_mode not in COMPILE_MODES:
            raise ValueError(f"compile_mode: must be one of {COMPILE_MODES}, got {self.compile_mode!r}")
        if self.local_diffusion not in LOCAL_DIFFUSIONS:
            raise ValueError(f"local_diffusion: must be one of {LOCAL_DIFFUSIONS}, got {self.local_diffusion!r}")
        if self.rotation_noise not in ROTATION_NOISES:
            raise ValueError(f"rotation_noise: must be one of {ROTATION_NOISES}, got {self.rotation_noise!r}")
        if self.use_rotation_noise and self.rotation_noise == "signal" and self.prediction_type != "sample":
            raise ValueError(
                "rotation_noise='signal': needs prediction_type='sample' (the target is the unturned goal); "
                "with another target use rotation_noise='paper' or use_rotation_noise=false"
            )
        if not 0.0 <= self.z_rotation_range <= 180.0:
            raise ValueError(f"z_rotation_range: degrees in [0, 180], got {self.z_rotation_range}")
        for name in ("rotation_loss_weight", "spread_loss_weight"):
            weight = getattr(self, name)
            if weight < 0:
                raise ValueError(f"{name}: must be >= 0, got {weight}")
            if weight > 0 and (self.prediction_type != "sample" or self.local_diffusion != "point"):
                raise ValueError(
                    f"{name}: needs prediction_type='sample' and local_diffusion='point' (it compares the "
                    "predicted clean goal points with the true ones)"
                )
        if not self.frame_loss_weight > 0:
            raise ValueError(f"frame_loss_weight: must be positive, got {self.frame_loss_weight}")
        if self.frame_loss_weight != 1.0 and not self.disentangled:
            raise ValueError("frame_loss_weight: needs disentangled=true (the joint diffusion has no frame of its own)")
        if self.frame_from_points and not (self.disentangled and self.local_diffusion == "point"):
            raise ValueError(
                "frame_from_points: needs disentangled=true and local_diffusion='point' (a frame and point outputs)"
            )
        if self.local_scene_points < 0:
            raise ValueError(f"local_scene_points: 0 (the whole scene) or positive, got {self.local_scene_points}")
        if self.local_scene_with_whole and not self.local_scene_points:
            raise ValueError("local_scene_with_whole: needs local_scene_points > 0 (the crop it is seen beside)")
        octaves = self.position_octaves
        if isinstance(octaves, bool) or not isinstance(octaves, int) or not 0 <= octaves <= MAX_POSITION_OCTAVES:
            raise ValueError(
                f"position_octaves: an integer in [0, {MAX_POSITION_OCTAVES}] (0: no Fourier positions), "
                f"got {self.position_octaves!r}"
            )
        if not 0.0 < self.gmm_batch_fraction <= 1.0:
            raise ValueError(f"gmm_batch_fraction: must lie in (0, 1], got {self.gmm_batch_fraction}")
        if self.gmm_frames not in GMM_FRAMES:
            raise ValueError(f"gmm_frames: must be one of {GMM_FRAMES}, got {self.gmm_frames!r}")
        check_frame_temperature(self.frame_temperature, self.disentangled)
        if self.prediction_type not in PREDICTION_TYPES:
            raise ValueError(f"prediction_type: must be one of {PREDICTION_TYPES}, got {self.prediction_type!r}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"sampler: must be one of {SAMPLERS}, got {self.sampler!r}")
        if self.local_diffusion == "se3" and not self.disentangled:
            raise ValueError("local_diffusion='se3' already separates rotation and translation; keep disentangled=true")
        if self.hidden_dim % self.num_heads:
            raise ValueError(f"hidden_dim ({self.hidden_dim}) must be divisible by num_heads ({self.num_heads})")
        check_inference_steps(self.num_inference_steps, self.num_train_timesteps)
        if self.point_scale is not None and not self.point_scale > 0:
            raise ValueError(f"point_scale: must be positive, got {self.point_scale}")
        for mode_name, mode in self.normalization_mapping.items():
            if mode_name in ("STATE", "ACTION") and mode is not NormalizationMode.IDENTITY:
                raise ValueError(
                    f"normalization_mapping[{mode_name!r}] must be IDENTITY: taxdpd scales point clouds "
                    "isotropically itself (per-axis normalisation would distort the geometry)"
                )

    @classmethod
    def for_point_clouds(cls, num_object_points: int, num_scene_points: int, **overrides) -> TaxDPDConfig:
        """A config with the dataset schema's features, for building a policy outside `lerobot-train`."""
        return cls(
            input_features={
                OBJECT_KEY: PolicyFeature(FeatureType.STATE, (num_object_points, 3)),
                SCENE_KEY: PolicyFeature(FeatureType.STATE, (num_scene_points, 3)),
            },
            output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (num_object_points, 3))},
            num_object_points=num_object_points,
            num_scene_points=num_scene_points,
            **overrides,
        )

    # ---- LeRobot hooks
    def get_optimizer_preset(self) -> FusedAdamWConfig:
        return FusedAdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    def validate_features(self) -> None:
        for key in (OBJECT_KEY, SCENE_KEY):
            if key not in self.input_features:
                raise ValueError(
                    f"taxdpd needs the input feature '{key}' (an (N, 3) point cloud); dataset features are "
                    f"{sorted(self.input_features)}"
                )
            shape = tuple(self.input_features[key].shape)
            if len(shape) != 2 or shape[1] != 3:
                raise ValueError(f"input feature '{key}': expected shape (N, 3), got {shape}")
        if ACTION_KEY not in self.output_features:
            raise ValueError(f"taxdpd needs the output feature '{ACTION_KEY}' (the goal cloud)")
        action_shape = tuple(self.output_features[ACTION_KEY].shape)
        object_shape = tuple(self.input_features[OBJECT_KEY].shape)
        if action_shape != object_shape:
            raise ValueError(
                f"'{ACTION_KEY}' {action_shape} and '{OBJECT_KEY}' {object_shape} must have the same shape: "
                "row i of the goal cloud is where point i of the object goes"
            )
        for key, feature in self.input_features.items():
            if key in (OBJECT_KEY, SCENE_KEY):
                continue
            if feature.type is FeatureType.VISUAL:
                raise ValueError(f"taxdpd takes point clouds only; remove the image feature '{key}'")

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None
