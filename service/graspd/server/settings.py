"""All service settings in one pydantic-settings object, read from GRASPD_* environment variables."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from graspd.gpd.classifier import DEFAULT_CASCADE_MODEL
from graspd.gpd.classifier import default_models_dir as models_dir


def available_cores() -> int:
    """CPU cores this process may run on (affinity-aware)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def default_models_dir() -> Path:
    return models_dir()


class Settings(BaseSettings):
    """Service configuration; every field can be set as GRASPD_<FIELD> (lists as JSON)."""

    model_config = SettingsConfigDict(env_prefix="GRASPD_", extra="ignore")

    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    models_dir: Path | None = Field(default=None, description="folder of <name>.onnx + <name>.json; None: models/")
    default_model: str | None = Field(default=None, description="model used when a request names none")
    model_threads: int = Field(default=1, ge=0, description="onnxruntime intra-op threads per model")
    cascade_model: str = Field(default=DEFAULT_CASCADE_MODEL, max_length=200,
                               description="the cascade's cheap first pass: a model of the models folder that scores "
                               "every candidate, so that the full model scores only the best (request option "
                               "cascade); used with every model made for the same hand; empty: no cascade")
    detect_workers: int = Field(default=0, ge=0, description="detections run at once; 0 = one per CPU core")
    threads: int = Field(default=0, ge=0, description="cores the running detections share (graspd.core.parallel: a "
                         "lone "
                         "request uses them all, concurrent ones divide them); 0 = every core of the process")
    warmup: bool = Field(default=True, description="run one detection on a small bundled cloud at start-up, before "
                         "the service answers, so that the first request is as fast as the rest (~1 s of start-up)")
    detect_memory_mb: float = Field(default=2048.0, ge=0, description="memory budget of the detections running at "
                                    "once (MiB; graspd.server.services.budget "
                                    "estimates each request's from its points, "
                                    "samples and crops): a request over the whole budget gets 413 naming the field, "
                                    "one that does not fit now waits detect_memory_wait_s, then 503 with "
                                    "Retry-After; 0: no budget")
    detect_memory_wait_s: float = Field(default=5.0, ge=0, description="a request whose detection does not fit the "
                                        "memory budget now waits this long on its worker for memory, then 503 (s)")
    queue_size: int = Field(default=32, ge=0, description="requests that may wait for a worker before 503")
    deadline_s: float = Field(default=30.0, gt=0, description="per-request deadline, queueing included (s): a "
                              "request starts only if its detection is expected to end within it (else 413 when it "
                              "never would, 503 when not now); a started one is awaited up to twice as long (504)")
    max_body_bytes: int = Field(default=64 << 20, gt=0, description="request size cap (bytes); larger gets 413")
    token: SecretStr | None = Field(default=None, description="bearer token required on /detect, /models and the "
                                     "template routes, and as the attachment of every Zenoh query and streamed cloud")
    publish_docs: bool = Field(default=False, description="with a token set, serve /docs, /redoc and /openapi.json "
                               "to anyone (without one they are public anyway)")
    publish_metrics: bool = Field(default=False, description="with a token set, serve /metrics to anyone")
    log_level: str = "INFO"
    log_json: bool = True
    zenoh_enabled: bool = True
    zenoh_mode: str = Field(default="peer", pattern="^(peer|client|router)$")
    zenoh_listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    zenoh_connect: list[str] = Field(default_factory=list)
    zenoh_multicast: bool = Field(default=False, description="multicast scouting (off: loopback, no router)")
    zenoh_config: Path | None = Field(default=None, description="Zenoh JSON5 config file (TLS/mTLS, user/password "
                                      "auth, access control); a key it sets wins over zenoh_mode/listen/connect/"
                                      "multicast, which fill in only the keys it leaves at Zenoh's defaults")
    zenoh_allow_anonymous: bool = Field(default=False, description="let Zenoh listen or connect beyond loopback "
                                        "with no token and no authentication in zenoh_config (trusted networks)")
    zenoh_admin_space: bool = Field(default=False, description="with a token set, keep the Zenoh admin space "
                                    "(@/<zid>/**: endpoints, peers, metrics) when zenoh_config enables it; off by "
                                    "default, since any peer reaching the session could read it without the token")
    zenoh_stream_token: bool = Field(default=True, description="with a token set, streamed clouds need it as "
                                     "their attachment too; false for zenoh-bridge-ros2dds, which cannot attach "
                                     "one (then guard <prefix>/cloud with zenoh_config's access control)")
    zenoh_prefix: str = "graspd"
    zenoh_instance: str = Field(default="", description="instance id for <prefix>/instances/<id>; '' = host-pid")
    zenoh_stream: bool = Field(default=True, description="subscribe <prefix>/cloud, publish <prefix>/grasps")
    stream_viewpoint: tuple[float, float, float] = Field(default=(0.0, 0.0, 0.0),
                                                         description="camera position for streamed clouds (m)")
    stream_num_samples: int = Field(default=500, ge=1)
    stream_options: dict[str, Any] = Field(default_factory=dict, description="detection options of streamed "
                                           "clouds and CDR queries: DetectRequest fields but cloud and crops, "
                                           "plus viewpoints; changed at run time by a JSON put on "
                                           "<prefix>/<stream_config_key>")
    stream_config_key: str = Field(default="config", description="key under the prefix taking stream options")
    stream_inputs: dict[str, str] = Field(default_factory=dict, description="input -> key under the prefix, "
                                          "over the defaults pointcloud2: cloud, cloud_sources, cloud_indexed, "
                                          "cloud_samples ('' turns one off, a leading / makes it absolute)")
    stream_outputs: dict[str, str] = Field(default_factory=dict, description="output -> key under the prefix, "
                                           "over the defaults json: grasps, grasp_config_list, pose_array: "
                                           "grasp_poses, moveit_grasps, marker_array: grasp_markers, errors")
    # ROS 2 natively over DDS (graspd serve --ros2; graspd.server.ros2, the extra graspd[ros2]); the clouds are
    # detected with the stream options above, laid over by ros2_options
    ros2_enabled: bool = Field(default=False, description="a DDS participant that ROS 2 nodes see as the node "
                               "/graspd: gpd_ros topics and the detect_grasps / plan_grasps services")
    ros2_domain_id: int = Field(default_factory=lambda: int(os.environ.get("ROS_DOMAIN_ID") or 0), ge=0, le=232,
                                description="DDS domain (ROS_DOMAIN_ID when unset)")
    ros2_distro: str = Field(default="jazzy", pattern="^(humble|iron|jazzy|kilted|rolling)$",
                             description="ROS 2 distribution of the peers (Humble's graph Gid and Humble/Iron's "
                             "MoveItErrorCodes differ on the wire)")
    ros2_node_name: str = Field(default="graspd", pattern=r"^[A-Za-z][A-Za-z0-9_]{0,63}$")
    ros2_namespace: str = Field(default="/", pattern=r"^/([A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*)?$",
                                description="node namespace; relative topic and service names go under it")
    ros2_topics: dict[str, str] = Field(default_factory=dict, description="ROS topic or service name per input, "
                                        "output and service over the defaults (graspd.server.ros2.names); '' "
                                        "turns one off")
    ros2_options: dict[str, Any] = Field(default_factory=dict, description="detection options of ROS 2 clouds "
                                         "and services laid over stream_options (camera_poses, points_frame, "
                                         "camera_frame_id, robot_frame_id, num_samples, ...)")
    ros2_discovery: str = Field(default="localhost", pattern="^(localhost|subnet|off)$", description="discovery "
                                "range as ROS_AUTOMATIC_DISCOVERY_RANGE; localhost also binds to loopback only")
    ros2_peers: list[str] = Field(default_factory=list, description="static DDS peers (addresses)")
    ros2_interfaces: list[str] = Field(default_factory=list, description="network interfaces for subnet discovery "
                                       "(default: Cyclone's choice)")
    ros2_socket_buffer_bytes: int | None = Field(default=None, ge=65536, description="UDP receive buffer the "
                                                 "node asks for (bytes; best-effort clouds of megabytes need several: "
                                                 "raise net.core.rmem_max to at least this); None: Cyclone's default")
    ros2_config: Path | None = Field(default=None, description="CycloneDDS XML file laid over graspd's own DDS "
                                     "configuration (its settings win)")
    ros2_allow_anonymous: bool = Field(default=False, description="allow subnet discovery or peers without DDS "
                                       "Security (trusted networks)")
    ros2_security_enclave: Path | None = Field(default=None, description="SROS2 enclave folder (identity and "
                                               "permissions certificates, governance.p7s, permissions.p7s): DDS "
                                               "Security for the participant")
    ros2_security_plugins: Path | None = Field(default=None, description="folder of the Cyclone DDS security "
                                               "plugins (libdds_security_auth/_ac/_crypto.so); None: the "
                                               "dynamic loader's path")
    ros2_finger_joints: list[str] = Field(default_factory=lambda: ["panda_finger_joint1", "panda_finger_joint2"],
                                          description="the hand's finger joints in moveit_msgs/Grasp postures; "
                                          "each is set to half the opening (m)")
    ros2_finger_squeeze_m: float = Field(default=0.01, ge=0, le=0.1, description="closed posture: the grasp "
                                         "width less this (m), so that the fingers press")
    ros2_finger_effort: float = Field(default=0.0, ge=0, description="closed posture's effort per finger joint "
                                      "(N; 0: none given)")
    ros2_plan_cloud_age_s: float = Field(default=10.0, gt=0, description="plan_grasps detects on the newest "
                                         "cloud received within this (s)")
    data_dir: Path | None = Field(default=None, description="service data folder (the template library's default "
                                  "SQLite file); None: $XDG_DATA_HOME/graspd, else ~/.local/share/graspd")
    template_library: str | None = Field(default=None, description="SQLAlchemy URL of the grasp-template library "
                                         "and feedback store; None: sqlite:///<data_dir>/templates.db")
    template_hand: str | None = Field(default=None, description="hand preset a new template library is made for; "
                                      "None: an existing library's hand, else 'gpd'")
    template_detections: int = Field(default=2000, ge=1, description="template detections the library keeps "
                                     "for feedback on their grasps (~0.3 MB each with their cloud); older ones are "
                                     "deleted and their ids answer 404")
    feedback_detections: int = Field(default=64, ge=0, description="recent GPD detections remembered in memory "
                                      "for POST /feedback (older ids answer 404)")
    feedback_memory_mb: float = Field(default=24.0, ge=0, description="memory cap of those remembered "
                                      "detections (MiB; their clouds, poses and widths)")
    allow_unscored: bool = Field(default=False, description="without a default model in the models folder, "
                                 "serve requests naming no model unscored (scored: false) instead of answering 503 "
                                 "and reporting not ready; for tests and ablations (a broken default is never "
                                 "allowed)")
    max_retry_after_s: float = Field(default=5.0, ge=1, description="largest Retry-After of a 503 (s); the "
                                     "clients wait at most 5 s between retries")
    http_keep_alive_s: float = Field(default=5.0, gt=0, description="idle keep-alive connections close after "
                                     "this (s)")
    http_header_timeout_s: float = Field(default=10.0, gt=0, description="a request line and headers must "
                                         "arrive within this (s), or the connection closes (slow clients)")
    http_body_timeout_s: float = Field(default=60.0, gt=0, description="the whole request body must arrive "
                                       "within this (s), or 408 and the connection closes (slow clients)")
    http_min_upload_rate: float = Field(default=16_384.0, ge=0, description="request bodies must arrive at this "
                                        "average rate after http_upload_grace_s, or 408 and the connection closes "
                                        "(bytes/s; 0: off)")
    http_upload_grace_s: float = Field(default=5.0, gt=0, description="time a request body may take before the "
                                       "minimum upload rate applies (s)")
    http_max_connections_per_peer: int = Field(default=64, ge=1, description="open HTTP connections of one client "
                                               "address at most; one more closes that address's oldest connection "
                                               "still waiting for its request headers, or is refused")
    http_max_connections: int = Field(default=256, ge=1, description="open HTTP connections at most; one more "
                                      "closes the oldest connection still waiting for its request headers, or is "
                                      "refused when none is (graspd.server.runner)")
    http_max_header_bytes: int = Field(default=64 << 10, ge=1024, description="request line and headers at "
                                       "most (bytes)")
    instance_training: bool = Field(default=True, description="POST /models may train instance models (a "
                                    "classifier fine-tuned for one uploaded mesh; needs graspd-lab)")
    instance_views: int = Field(default=24, ge=3, le=200, description="rendered views of an instance's mesh (a "
                                "quarter held out for its comparison, an eighth for validation)")
    instance_per_view: int | None = Field(default=None, ge=2, le=1024, description="exemplars kept per view; "
                                          "None: the training default (128)")
    instance_epochs: int | None = Field(default=None, ge=1, le=200, description="most fine-tuning epochs; None: "
                                        "the training default (30, within instance_max_minutes)")
    instance_max_minutes: float = Field(default=2.0, gt=0, le=120, description="fine-tuning time of one instance "
                                        "model (min)")
    instance_threads: int = Field(default=1, ge=1, description="torch threads of a training job (it shares the "
                                  "cores with detection)")
    instance_queue: int = Field(default=2, ge=0, description="instance jobs that may wait behind the running one "
                                "before POST /models answers 503")
    instance_max_mesh_bytes: int = Field(default=16 << 20, gt=0, description="largest mesh upload (bytes)")
    instance_check_workers: int = Field(default=1, ge=1, le=8, description="uploaded meshes checked at once (each "
                                        "in a process of its own, ~300-400 MB while it runs)")
    instance_check_queue: int = Field(default=4, ge=0, description="mesh checks that may wait for a worker; more "
                                      "get 503 with Retry-After")
    instance_check_memory_mb: int = Field(default=2048, ge=0, description="address-space limit of a mesh check's "
                                          "process (RLIMIT_AS, MiB; the libraries alone map ~1.1 GB, a 300k-triangle "
                                          "mesh peaks at ~1.3 GB; 0: none)")
    instance_check_timeout_s: float = Field(default=60.0, gt=0, description="a mesh check running (CPU time) or "
                                            "waiting longer fails: 422 (running) or 503 (waiting) (s)")
    instance_timeout_s: float = Field(default=1800.0, gt=0, description="a training job running longer is "
                                      "stopped and fails (s)")
    shutdown_grace_s: float = Field(default=35.0, ge=0, description="on SIGTERM: time running requests get "
                                    "to finish before connections are closed (s)")

    @property
    def workers(self) -> int:
        return self.detect_workers or available_cores()

    def resolved_models_dir(self) -> Path:
        return self.models_dir if self.models_dir is not None else default_models_dir()

    def resolved_data_dir(self) -> Path:
        """data_dir, else $XDG_DATA_HOME/graspd, else ~/.local/share/graspd."""
        if self.data_dir is not None:
            return self.data_dir
        xdg = os.environ.get("XDG_DATA_HOME")
        return (Path(xdg) if xdg else Path.home() / ".local" / "share") / "graspd"

    def resolved_template_library(self) -> str:
        """template_library, else an SQLite file templates.db in the data folder."""
        return self.template_library or f"sqlite:///{self.resolved_data_dir() / 'templates.db'}"
