"""The user documentation of the environments (their class docstrings): Gymnasium's sections
(description, action and observation spaces, rewards, starting state, episode end, arguments)."""

__all__ = ["ROLL_DOC", "SHAPE_DOC"]

ROLL_DOC = r"""
    Rolling locomotion of a tensegrity robot on flat ground (``TensegrityRoll-v0``).

    ## Description
    A free class-1 tensegrity robot (default: a 3-bar prism lying on its side; ``structure=
    "icosahedron"``: the 6-bar SUPERball shape) rests on the ground under gravity (-9.81 m/s^2
    along z). The policy changes the rest lengths (``action_mode="rest_length"``, motor-driven
    cables with a maximum cable speed and rest-length limits) or the force densities
    (``action_mode="force_density"``) of its strings and must roll the robot's centre of mass
    along the goal direction (+x by default). Dynamics: the exact configuration-matrix equations
    of Skelton & de Oliveira ch. 5 (rigid rods, tension-only damped strings), with ground
    contact at the rods' end caps (compliant Hunt-Crossley normal force, Coulomb friction with a
    stick phase; :mod:`tensegrity_gym.physics.contact`, ``docs/contact.md``). Semi-implicit Euler at
    ``dt`` = 1 ms, ``frame_skip`` = 20 (50 Hz control); contact forces are computed once per
    physics step for the whole batch and held over it.

    ## Scene (default robot)
    | quantity | prism (default) | icosahedron |
    |----------|-----------------|-------------|
    | rods | 3 x 0.383 m, 0.2 kg each | 6 x 0.40 m, 0.2 kg each |
    | strings | 9 (3 bottom, 3 top, 3 vertical), 1000 N/m, 2 N s/m | 24, 1000 N/m, 2 N s/m |
    | prestress | 20 N in the vertical strings | 10 N in every string |
    | shape | radius 0.15 m, height 0.25 m, twist 30 deg | rod pairs 0.2 m apart |
    | end caps | radius 0.02 m, friction 1.0 | same |
    | ground | k = 1e4 N/m, Hunt-Crossley d = 10 s/m; k_t = 1e4 N/m, c_t = 10 N s/m | same |

    Why: rods of ~0.35-0.4 m and ~0.2 kg are the scale of the 3-bar prism robots built in labs
    (a few hundred grams per actuated rod); 1000 N/m strings (an elastic cord or a spring in
    series with each cable, as most such robots use) keep the robot stiff under its own weight
    (it sags by 1.8 mm (prism) and 8 mm (icosahedron) when it settles on the ground) while the highest string frequency (~250 rad/s) and the contact frequency
    (~450 rad/s for k = 1e4 N/m on a rod end of effective mass m/4) allow explicit steps of a few
    ms: the estimated limit of semi-implicit Euler with contact and damping is 2.6 ms
    (:func:`tensegrity_gym.physics.contact.stable_step`; measured: stable at 2 ms, unstable at 3 ms), so
    the default 1 ms has a margin of 2-2.5x.
    Caps of 2 cm radius with friction 1 model rubber feet. The prism lies on a side face (the
    face of its convex hull with the largest stability margin, not top or bottom) with its axis
    along y, so rolling over its side faces moves it along x. The icosahedron rests on its most
    stable face.

    ## Action space
    ``Box(-1, 1, (na,), float32)``, one entry per actuated string (``actuated``, default all
    strings, in the structure's string order). Out-of-box entries are clipped (``clip_actions=
    False``: ``ValueError``); a NaN or inf entry raises ``ValueError`` naming its index.

    | mode | action a_i in [-1, 1] does | bounds |
    |------|---------------------------|--------|
    | ``rest_length`` | commands the cable speed v_cmd,i = a_i * ``max_cable_speed`` (0.2 m/s); the motor's speed v_i follows it at most ``max_cable_acceleration`` (2 m/s^2) fast; l0_i += v_i * dt_c (m) | ``rest_length_bounds`` x nominal (0.5 to 1.1) |
    | ``force_density`` | force density g_i += a_i * ``force_density_rate`` * dt_c (N/m) | [0, ``force_density_max``] (3 x the largest nominal) |

    with dt_c = ``dt * frame_skip`` = 0.02 s. The control is held over the control step.

    Cable motor model (``rest_length`` mode). Each control step, per actuated cable::

        v_cmd = a * max_cable_speed                                       # m/s
        v    <- v + clip(v_cmd - v, -max_cable_acceleration * dt_c, +max_cable_acceleration * dt_c)
        l0   <- clip(l0 + v * dt_c, low, high)
        v    <- 0 where l0 is on a bound and v pushes beyond it            # end stop

    and ``v = 0`` at reset. The cable speed v is state and is observed (block
    ``cable_speed``). Why 2 m/s^2: the robots this env models (NTRT's and the Rutgers /
    Berkeley 3-bar prisms) wind their cables on spools driven by small geared DC motors, which
    reach full cable speed in about 0.1 s (motor time constant plus the spool's and gearbox's
    inertia, current-limited drivers); 0.2 m/s in 0.1 s is 2 m/s^2, i.e. the cable speed can
    reverse fully (-0.2 to +0.2 m/s) in 0.2 s, 10 control steps. Without such a limit a policy
    can flip every cable between full speed in and out at every control step (25 Hz bang-bang)
    and shuffle the robot forward by vibration instead of rolling it, which no real motor
    could do. ``max_cable_acceleration=None`` removes the limit: the rest-length rate is then
    a_i * ``max_cable_speed`` at once (the behaviour before this motor model; no
    ``cable_speed`` block). ``force_density`` mode ignores the argument.

    ## Observation space
    ``Box(-inf, inf, (6 n + na + 2 k + 3 + ns,), float32)`` with ns = na (the cable speeds) in
    ``rest_length`` mode with the motor model (the default) and ns = 0 otherwise (prism: n = 6
    nodes, k = 3 rods, na = 9: size 63, or 54 with ``max_cable_acceleration=None`` or in
    ``force_density`` mode; icosahedron: n = 12, k = 6, na = 24: size 135, or 111):

    | index | observation | unit |
    |-------|-------------|------|
    | 0 .. 3n-1 | node positions relative to the centre of mass (x, y, z per node) | m |
    | 3n .. 6n-1 | node velocities | m/s |
    | 6n .. 6n+na-1 | control of each actuated string: rest length or force density | m or N/m |
    | 6n+na .. 6n+na+2k-1 | contact flag of each end cap (rod 0 end a, rod 0 end c, ...) | 0/1 |
    | next 2 | goal direction (unit vector in the ground plane) | 1 |
    | next 1 | height of the centre of mass | m |
    | last ns | cable speed v_i of each actuated string (motor model only; positive: lengthening) | m/s |

    The absolute x, y position is not observed (as Ant/Hopper exclude it by default).
    ``env.unwrapped.task.observation_layout()`` lists the blocks.

    ## Rewards
    ``reward = reward_forward + reward_ctrl``:

    * ``reward_forward = forward_reward_weight * (c_xy(t + dt_c) - c_xy(t)) . goal / dt_c``:
      the centre of mass's velocity along the goal direction, m/s (weight 1);
    * ``reward_ctrl = -ctrl_cost_weight * sum_i a_i^2`` (weight 0.01).

    Each term is in ``info`` as ``reward_<name>``; their sum is the reward exactly.

    ## Info
    ``com_position`` (3,) m, ``com_velocity`` (3,) m/s (mean over the control step),
    ``forward_velocity`` m/s, ``distance_rolled`` (displacement of the centre of mass along the
    goal since reset, m), ``diverged``, the ``reward_*`` terms; at reset also ``goal_direction``.

    ## Starting state
    The robot at rest on the ground: placed on its face and settled under gravity for 1.5 s at
    construction (nominal rest lengths). Each reset adds uniform noise of +-``reset_noise_scale``
    (default 1 mm) to the rods' centres (m), of +-``reset_noise_scale``/l to their unit vectors,
    and the same (m/s) to their velocities; the copy is lifted if a cap went further into the
    ground than at rest. All contacts start released (anchors are set at the first contact).
    Goal: ``goal_direction`` (default +x), or, with ``randomize_goal=True``, a uniform random
    direction in the ground plane. All randomness comes from ``np_random``.

    ## Episode end
    No termination (a tensegrity cannot fall over). Truncation: by the time limit at
    registration (``max_episode_steps`` = 1000 control steps = 20 s), and at once with
    ``info["diverged"] = True`` if the state becomes non-finite, a rod moves more than
    ``divergence_limit`` from the robot's centre (the structure blew apart) or that centre more
    than ``divergence_limit`` up or down from the start; the state is then put back to the last
    finite one, so observations stay finite. Horizontal travel is not limited.

    ## Arguments
    ``gymnasium.make("TensegrityRoll-v0", **kwargs)``, or grouped: ``config=`` a
    :class:`tensegrity_gym.envs.config.RollConfig` (groups robot, simulation, actuation, contact, reward, goal, terrain, observation, randomization; defaults
    ``roll_config()``), each keyword below then replacing its field of ``config``:

    | argument | default | meaning |
    |----------|---------|---------|
    | ``structure`` | ``"prism"`` | ``"prism"``, ``"icosahedron"``, or any free ``Structure``/builder name/JSON path (gravity added if missing) |
    | ``action_mode`` | ``"rest_length"`` | or ``"force_density"`` |
    | ``actuated`` | ``None`` (all) | string indices or boolean mask |
    | ``integrator`` | ``"semi_implicit_euler"`` | (``"rk4"`` holds contact forces over each step: first order in contact) |
    | ``dt``, ``frame_skip`` | ``1e-3``, ``20`` | physics step (s), steps per control step |
    | ``allow_unstable_dt`` | ``False`` | a ``dt`` above the estimated stability limit (strings + contact), also for the worst-case draw of ``params`` / ``randomize``, raises ValueError unless True (then it warns) |
    | ``string_damping`` | ``2.0`` | N s/m on every string (``None``: the structure's) |
    | ``forward_reward_weight``, ``ctrl_cost_weight`` | ``1.0``, ``0.01`` | reward weights |
    | ``goal_direction``, ``randomize_goal`` | ``(1, 0)``, ``False`` | goal in the ground plane |
    | ``reset_noise_scale`` | ``1e-3`` | m, m/s |
    | ``max_cable_speed`` | ``0.2`` | m/s (rest-length mode) |
    | ``max_cable_acceleration`` | ``2.0`` | m/s^2, cable motor acceleration limit (rest-length mode; ``None``: none, the speed follows the action at once) |
    | ``rest_length_bounds`` | ``(0.5, 1.1)`` | fractions of the nominal rest lengths |
    | ``force_density_max``, ``force_density_rate`` | ``None`` | N/m, N/(m s) (force-density mode only; an error in rest-length mode) |
    | ``friction`` | ``1.0`` | Coulomb coefficient of the caps |
    | ``ground_stiffness``, ``ground_damping`` | ``1e4``, ``10`` | N/m, s/m (Hunt-Crossley) |
    | ``tangential_stiffness``, ``tangential_damping`` | ``None`` (= ground_stiffness), ``10`` | N/m, N s/m (stick spring) |
    | ``cap_radius`` | ``0.02`` | m |
    | ``ground_max_damping`` | ``None`` (= m/(4 dt), 50 N s/m) | N s/m, cap on the Hunt-Crossley damping coefficient (explicit stability in fast impacts) |
    | ``rod_contact`` | ``None`` | rod-rod contact (capsules that push each other apart; ``docs/contact.md`` "Rod-rod contact"): ``None`` or ``False`` off (rods pass through each other; no rod-rod code runs, outputs unchanged); ``True``, a ``RodContact`` or a dict of its fields (``radius`` m, 0.005; ``stiffness`` N/m, 5e4; ``damping`` N s/m, 10; ``friction``, 0.5; ``max_damping`` N s/m, default m/(8 dt); ``friction_speed`` m/s, 0.01). the NumPy envs and the torch device env (refused by the MuJoCo twin) |
    | ``backend`` | ``"auto"`` | ``"auto"`` / ``"numba"`` (the same: the numba kernels; ``"numpy"`` is no longer a backend) |
    | ``divergence_limit`` | ``None`` | m (default 100 x the robot's size) |
    | ``clip_actions`` | ``True`` | clip out-of-box actions (``False``: raise) |
    | ``params`` | ``None`` | fix robot parameters by name, absolute SI values (``rod_mass``, ``stiffness``, ``damping``, ``node_damping``, ``gravity``, ``rest_length_offset``, ``friction``, ``ground_stiffness``, ``ground_damping``, ``max_cable_speed``, ``max_cable_acceleration``; a number or one per rod/string/node/cable): see :mod:`tensegrity_gym.envs.domain` |
    | ``randomize`` | ``None`` | ``{name: spread}`` drawn per copy at every reset (relative U(1 - s, 1 + s) x nominal; ``rest_length_offset`` absolute U(-s, s) m); ``info["params"]`` at reset reports the values |
    | ``action_delay`` | ``0`` | control steps between an action and its effect (zeros at the start of an episode) |
    | ``start_rest_length_offset`` | ``None`` | m added to the actuated cables' rest lengths at reset (a slack start; must stay within the bounds) |
    | ``observation_mode`` | ``"state"`` | ``"robot"``: what a lab robot senses (cable lengths, motor encoders and speeds, rod IMUs, contact switches, goal; :mod:`tensegrity_gym.envs.sensors`) |
    | ``sensor_noise`` | ``None`` | robot mode: ``{block: sigma}`` Gaussian noise, SI units (``cable_length``, ``control``, ``cable_speed``, ``imu_accel``, ``imu_gyro``); ``contact``: the probability p that a switch reads wrong |
    | ``history`` | ``1`` | robot mode: readings stacked, newest first |
    | ``terrain`` | ``None`` | the ground: ``None`` or ``{}`` level ground at z = 0 (unchanged, the fast path); a terrain file's dict, its JSON path or a ``Terrain`` (sloped plane, boxes, heightfield; ``docs/terrain.md``), the same every episode; or a generator drawn per episode and copy from ``np_random``: ``{"generator": "slope" / "steps" / "rough", ...}`` or a ``TerrainGenerator`` (:mod:`tensegrity_gym.tasks.terrain`). Its contact values default to ``friction``, ``ground_stiffness``, ``ground_damping``. The NumPy envs, the torch device vector env (``backend="torch"``, host resets only) and the MuJoCo twin take it |
    | ``terrain_difficulty`` | ``1.0`` | in [0, 1]: scale of a generated terrain (slope, step height, bump amplitude); a curriculum changes it between episodes with ``task.set_terrain_difficulty(d)`` |
    | ``render_mode``, ``width``, ``height`` | ``None``, 480, 480 | ``"rgb_array"`` or ``"human"`` |

    ``render()`` draws the rods, the strings coloured by tension, the ground, the path of the
    centre of mass (orange) and a star 0.5 m ahead of it along the goal.

    On a terrain the robot starts where it would on level ground (a generated terrain keeps a
    level pad around the start), lifted clear of the terrain under it if need be; the contact
    flags of the observation are the rod ends' contacts with any part of the terrain, and
    ``goal_direction`` is the direction a generated slope or staircase rises along.

    ## Baseline
    :class:`tensegrity_gym.tools.baselines.RollingGait` (no learning): a periodic contraction wave of
    rest lengths around the prism's axis (period 1.71 s, open loop in time) that rolls the prism
    face over face, steered by one fed-back scalar (the top/bottom rest-length bias, from the
    heading of the observed centre-of-mass velocity). ``python -m scripts.eval.eval_roll_baseline``
    (100 s on flat ground, 8 reset seeds, default env; ``results/roll_baseline.json``): goal +x
    0.196 m/s along the goal (min 0.191) = 0.51 body lengths/s (body length = rod length
    0.383 m), 0.250 m/s = 0.65 body lengths/s after the first 20 s; random goals 0.232 m/s. From
    the reset pose the wave rolls the prism toward -x first and the feedback turns it round in
    its first 15-20 s, so in one registered 20 s episode it gains little (about 0 m). It
    rolls: +18.9 net turns about the axis across the goal in 100 s
    (``scripts/eval/gait_stats.py gait --steps 5000``). The same wave without the feedback
    (``steer=0``, purely open loop) rolls as fast over the ground (0.244 m/s) but in circles:
    -0.085 m/s along +x.

    ## Version history
    * v0: initial version.
    * v0 (0.2): ``params``, ``randomize``, ``action_delay``, ``start_rest_length_offset``, ``observation_mode="robot"``, ``sensor_noise``, ``history``; defaults unchanged (bit-identical).
    * v0 (0.3): ``sensor_noise={"contact": p}`` (contact switches that read wrong with probability p); the torch vector env has ``observation_mode="robot"``.
    * v0 (motor model): rest-length mode got a cable acceleration limit
      (``max_cable_acceleration``, default 2 m/s^2; the cable speed is now state, reset to 0,
      stopped at the rest-length bounds) and the cable speeds were appended to the observation
      (block ``cable_speed``; prism 54 -> 63 entries). This changes the default dynamics and
      observation of rest-length mode (the id was kept): policies trained before it need
      ``max_cable_acceleration=None``, which reproduces the old env exactly.
      ``force_density`` mode is unchanged.
    * v0 (argument checks): force-density limits in rest-length mode, non-bool flags and non-integer counts
      are ValueErrors naming the argument (were ignored or converted); valid arguments unchanged.
    * v0 (one backend): ``backend="numpy"`` is refused (the NumPy step path became the test oracle);
      reset states are projected by the numba kernels, which differ from the old NumPy projection
      by round-off only (1e-16 m).
    * v0 (rod-rod contact): ``rod_contact`` (default ``None``: off, outputs bit-identical).
"""


SHAPE_DOC = r"""
    Shape tracking with an anchored class-1 tensegrity (``TensegrityShape-v0``).

    ## Description
    A tensegrity whose rigid-body motion is removed by node constraints (default: the
    seed's Example 5.8 three-bar prism, node 0 pinned at the origin, node 1 sliding on the
    x axis, node 2 sliding on the plane z = 0; gravity -9.81 m/s^2 along z) must take a
    commanded shape. The policy changes the rest lengths (``action_mode="rest_length"``)
    or the force densities (``action_mode="force_density"``) of the actuated strings. The
    dynamics are the exact configuration-matrix equations of Skelton & de Oliveira ch. 5
    (tension-only strings, rigid rods), integrated with ``integrator`` at ``dt`` seconds,
    ``frame_skip`` physics steps per control step (default 1 ms x 20 = 50 Hz control). No
    contact code runs. Every target is reachable by construction: it is a stable static
    equilibrium for admissible controls (see "Starting state").

    Damping (defaults chosen so that a 2 cm disturbance decays below 1 mm in about 0.7 s):
    ``string_damping`` = 5 N s/m on every elastic string (``None`` keeps the structure's own)
    and ``node_damping`` = 2 N s/m of viscous drag on every rod node (string damping alone
    cannot damp the prism's infinitesimal mechanism, whose motion does not stretch the strings
    to first order). The drag is part of the physics model (``core.model.compile_model(...,
    node_damping=c)``: force ``-c v`` on every rod node, evaluated wherever the integrator
    evaluates forces), so a control step is one integrator call of ``frame_skip`` steps.
    In force-density mode the actuated strings are ideal force actuators with no elastic or
    damping part, so only the remaining strings and the node drag dissipate energy.

    ## Action space
    ``Box(-1, 1, (na,), float32)``, one entry per actuated string (``actuated``, default all
    strings, in the structure's string order). Actions outside [-1, 1] are **clipped** to the
    box (as actuators saturate; SB3 and random agents act inside it); construct with
    ``clip_actions=False`` to get a ``ValueError`` instead. A NaN or inf entry always raises
    ``ValueError`` naming its index.

    | mode | action a_i in [-1, 1] does | control bounds |
    |------|---------------------------|----------------|
    | ``rest_length`` | rest length l0_i += a_i * ``max_speed`` * dt_c (m), dt_c = dt * frame_skip | ``rest_length_bounds`` x the structure's rest length (default 0.8 to 1.1) |
    | ``force_density`` | force density g_i += a_i * ``force_density_rate`` * dt_c (N/m) | [0, ``force_density_max``] (default 3 x the largest nominal force density; never negative) |

    The control then holds (zero-order hold) over the control step.

    ## Observation space
    ``Box(-inf, inf, (12 nt + na,), float32)``, with nt tracked nodes (every rod node that
    is not pinned: nodes 1-5 for the default prism, nt = 5, na = 9, size 69). Blocks:

    | index | observation | unit |
    |-------|-------------|------|
    | 0 .. 3nt-1 | positions of the tracked nodes (x, y, z per node, in node order) | m |
    | 3nt .. 6nt-1 | velocities of the tracked nodes | m/s |
    | 6nt .. 6nt+na-1 | current control of each actuated string: rest length (m) or force density (N/m) | m or N/m |
    | 6nt+na .. 9nt+na-1 | target positions of the tracked nodes | m |
    | 9nt+na .. 12nt+na-1 | target error (target - position) | m |

    ``env.unwrapped.task.observation_layout()`` lists the blocks.

    **Robot observation** (``observation_mode="robot"``): only what a lab robot measures, plus
    the target (a command, as the state mode gives it); no node position, velocity or target
    error. One reading, k rods, m strings (:mod:`tensegrity_gym.envs.sensors`, the code
    ``TensegrityRoll-v0`` uses; size m + na + 6k + 3nt, 51 for the default prism):

    | block | size | unit | reading |
    |-------|------|------|---------|
    | ``cable_length`` | m | m | length of every string (cable length sensor) |
    | ``control`` | na | m or N/m | each actuated string's motor encoder: its commanded rest length (N/m: force density) |
    | ``imu_accel`` | 3k | m/s^2 | each rod's accelerometer at its centre of mass in the rod frame: specific force a - g over the last physics step (reset reading: -g) |
    | ``imu_gyro`` | 3k | rad/s | each rod's angular velocity in the rod frame (z, about the rod axis, is 0) |
    | ``target_position`` | 3nt | m | target positions of the tracked nodes (the command) |

    The rod frame (z along the rod, x the world "up" made perpendicular to it) is defined in
    :mod:`tensegrity_gym.envs.sensors`. ``sensor_noise={block: sigma}`` adds Gaussian noise
    (SI units, from ``np_random``) to ``cable_length``, ``control``, ``imu_accel``, ``imu_gyro``;
    ``history=H`` stacks the last H readings, newest first (size H x the reading). Robot mode
    runs the same physics (the control step's ``frame_skip`` physics steps as two calls, so the
    IMUs see the last one; same trajectory, rewards and infos as the state mode) on the NumPy
    path of the observation (no fused compiled step).

    ## Rewards
    ``reward = reward_tracking + reward_proximity + reward_ctrl`` with e_i the distance of
    tracked node i from its target (m):

    * ``reward_tracking = -tracking_weight * mean_i e_i`` (``tracking_weight`` 1/m, default 10);
    * ``reward_proximity = proximity_weight * tolerance(max_i e_i, (0, tol), margin = 10 tol)``,
      a Gaussian bonus (dm_control's ``tolerance``; 1 within the success tolerance, 0.1 at 10 tol);
    * ``reward_ctrl = -ctrl_cost_weight * sum_i a_i^2``.

    Each term is in ``info`` as ``reward_<name>``; their sum is the reward exactly.

    ## Info
    ``tracking_error`` (mean e_i, m), ``max_node_error`` (max e_i, m), ``is_success``
    (every tracked node within ``success_tolerance``, default 1% of the structure's height:
    1 cm for the default prism), ``diverged`` (see "Episode end"), and the ``reward_*`` terms.

    ## Starting state
    At reset a target is drawn: rest lengths of the actuated strings uniform within
    +-``target_range`` (default 10%) of the structure's (clipped to the rest-length bounds); the
    stable equilibrium they give (statics.solve_equilibria from the nominal shape) is the
    target shape. Draws are redrawn unless the equilibrium is stable and every actuated
    string is taut; in force-density mode also unless its force densities lie within the
    bounds. In force-density mode the target is then an exact equilibrium of the actuated
    strings held at those force densities -- but, with no elastic stiffness left in them, not
    a stable one: for the default prism with all strings actuated, constant force densities
    leave three nearly neutral modes (stiffness about -2 N/m, i.e. slowly unstable under
    gravity), so holding a shape needs feedback (as the NNLS baseline does). The structure
    starts at the nominal equilibrium (the structure's rest lengths, under gravity) with
    uniform noise of +-``reset_noise_scale`` (m, m/s) on each reduced coordinate and
    velocity; the controls start at their nominal values. All randomness comes from
    ``np_random``.

    ## Episode end
    No termination: holding the shape is the task. Truncation: by the time limit set at
    registration (``max_episode_steps`` = 200 control steps = 4 s), and at once with
    ``info["diverged"] = True`` if the state becomes non-finite or a node moves more than
    ``divergence_limit`` (default 100 x the structure's size) from it; the state is then
    put back to the last finite one, so observations stay finite.

    ## Arguments
    ``gymnasium.make("TensegrityShape-v0", **kwargs)``, or grouped: ``config=`` a
    :class:`tensegrity_gym.envs.config.ShapeConfig` (groups robot, simulation, actuation, reward, target, observation, randomization; defaults
    ``shape_config()``), each keyword below then replacing its field of ``config``:

    | argument | default | meaning |
    |----------|---------|---------|
    | ``structure`` | ``"constrained_prism"`` | builder name, JSON path or ``Structure`` with node constraints or anchors |
    | ``action_mode`` | ``"rest_length"`` | or ``"force_density"`` |
    | ``actuated`` | ``None`` (all) | string indices or boolean mask |
    | ``integrator`` | ``"semi_implicit_euler"`` | fixed-step integrator (``"rk4"``) |
    | ``dt`` | ``1e-3`` | physics step, s (default well under the explicit limit, 0.025 s for the default prism) |
    | ``allow_unstable_dt`` | ``False`` | a ``dt`` above the integrator's estimated stability limit, also for the worst-case draw of ``params`` / ``randomize``, raises ValueError unless True (then it warns) |
    | ``frame_skip`` | ``20`` | physics steps per control step |
    | ``string_damping`` | ``5.0`` | N s/m on every string, ``None`` keeps the structure's |
    | ``node_damping`` | ``2.0`` | N s/m viscous drag on every rod node |
    | ``tracking_weight``, ``proximity_weight``, ``ctrl_cost_weight`` | ``10.0``, ``1.0``, ``0.01`` | reward weights |
    | ``success_tolerance`` | ``None`` (1% of the height) | m |
    | ``reset_noise_scale`` | ``5e-3`` | m, m/s |
    | ``target_range`` | ``0.1`` | relative rest-length range of target draws |
    | ``rest_length_bounds`` | ``(0.8, 1.1)`` | fractions of the structure's rest lengths |
    | ``max_speed`` | ``0.1`` | m/s, rest-length mode |
    | ``force_density_max``, ``force_density_rate`` | ``None`` | N/m and N/(m s); default 3 x the largest nominal force density and twice that per second (force-density mode only; an error in rest-length mode) |
    | ``backend`` | ``"auto"`` | ``"auto"`` / ``"numba"`` (the same: the numba kernels) |
    | ``divergence_limit`` | ``None`` | m |
    | ``clip_actions`` | ``True`` | clip out-of-box actions (``False``: raise) |
    | ``params`` | ``None`` | fix robot parameters by name, absolute SI values (``rod_mass``, ``stiffness``, ``damping``, ``node_damping``, ``gravity``, ``rest_length_offset``; a number or one per rod/string/node): see :mod:`tensegrity_gym.envs.domain`. Targets stay those of the nominal model (a controller that believes the nominal model then meets a different robot) |
    | ``randomize`` | ``None`` | ``{name: spread}`` drawn per copy at every reset (relative U(1 - s, 1 + s) x nominal; ``rest_length_offset`` absolute U(-s, s) m); ``info["params"]`` at reset reports the values |
    | ``action_delay`` | ``0`` | control steps between an action and its effect (zeros at the start of an episode) |
    | ``start_rest_length_offset`` | ``None`` | m added to the actuated strings' rest lengths at reset (rest-length mode; within the bounds) |
    | ``observation_mode`` | ``"state"`` | ``"robot"``: what a lab robot senses (cable lengths, motor encoders, rod IMUs) plus the target; see "Observation space" |
    | ``sensor_noise`` | ``None`` | robot mode: ``{block: sigma}`` Gaussian noise, SI units (``cable_length``, ``control``, ``imu_accel``, ``imu_gyro``) |
    | ``history`` | ``1`` | robot mode: readings stacked, newest first |
    | ``render_mode``, ``width``, ``height`` | ``None``, 480, 480 | ``"rgb_array"`` or ``"human"`` |

    ``render()`` draws rods thick, strings coloured by tension (slack dashed grey) and the
    targets as green circles; ``metadata["render_fps"]`` = 1 / (dt frame_skip).

    ## Version history
    * v0: initial version.
    * v0 (0.2): ``params``, ``randomize``, ``action_delay``, ``start_rest_length_offset``; defaults unchanged (bit-identical).
    * v0 (0.2): ``observation_mode="robot"``, ``sensor_noise``, ``history``; defaults unchanged (bit-identical).
    * v0 (argument checks): force-density limits in rest-length mode, non-bool flags and non-integer counts
      are ValueErrors naming the argument (were ignored or converted); valid arguments unchanged.
    * v0 (one backend): ``backend="numpy"`` is refused (the NumPy step path became the test oracle);
      reset states are projected by the numba kernels, which differ from the old NumPy projection
      by round-off only (1e-16 m).
    * v0 (rod-rod contact): ``rod_contact`` (default ``None``: off, outputs bit-identical).
"""
