"""``--env.type=univtac``: the LeRobot ``EnvConfig`` of the univtac-data tasks (needs lerobot 0.4.x)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_env_univtac.env import NAMESPACE, gym_id
from lerobot_env_univtac.features import env_features, features_map
from univtac_data.generators.tasks.base import TaskConfig, time_limited_steps
from univtac_data.generators.tasks.registry import task_class


@EnvConfig.register_subclass("univtac")
@dataclass
class UnivtacEnv(EnvConfig):
    """A univtac-data task (``--env.task``, a name of ``univtac-data list tasks``). Match ``fps``, ``sensor``,
    ``contact``, ``cameras`` and the camera size to the episodes a policy was trained on (``fps``: the export's
    rate, which must divide into the simulator's control ticks: 50, 25, 10 ... Hz)."""

    task: str | None = "lift_can"
    fps: int = 50
    episode_length: int | None = None  # policy steps before truncation; None: the task's own (time) limit at fps
    sensor: str = "gelsight_mini"
    contact: str = "geometric"  # the tactile contact model of the images: geometric or elastic
    cameras: bool = True  # the head and wrist cameras (False: tactile images and state only)
    camera_width: int = 480  # px
    camera_height: int = 270  # px
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.task is None:
            raise ValueError("--env.task is required (e.g. lift_can)")
        if self.episode_length is None:
            self.episode_length = time_limited_steps(task_class(self.task).max_steps, float(self.fps))
        specs = env_features(self.task, self._task_config())
        self.features = {f.env_key: PolicyFeature(type=FeatureType[f.kind], shape=f.shape) for f in specs}
        self.features_map = features_map(specs)

    def _task_config(self) -> TaskConfig:
        return TaskConfig(sensor=self.sensor, contact_method=self.contact, rate_hz=float(self.fps),  # type: ignore[arg-type]
                          cameras=self.cameras, camera_size=(self.camera_width, self.camera_height))

    @property
    def package_name(self) -> str:
        return NAMESPACE

    @property
    def gym_id(self) -> str:
        assert self.task is not None
        return gym_id(self.task)

    @property
    def gym_kwargs(self) -> dict:
        return {"sensor": self.sensor, "contact": self.contact, "cameras": self.cameras,
                "camera_width": self.camera_width, "camera_height": self.camera_height, "rate_hz": float(self.fps),
                "max_episode_steps": self.episode_length}
