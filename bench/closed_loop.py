"""Closed-loop ablation of the controller, judged exactly: ``python bench/closed_loop.py``.

    python bench/closed_loop.py --quick
    python bench/closed_loop.py --links 4,5,7 --seeds 5 --envs 20 --variants release,ours,paper
    python bench/closed_loop.py --variants ours,ours-check --scenarios cluttered --seeds 20
    python bench/closed_loop.py --variants ours,ours:target_ess=0.05:noise_smoothing=0.5 --links 4

A variant is the ``release`` or ``ours`` preset of ``scenarios.presets`` with
some MPPIConfig fields changed (``VARIANTS``): ``ours`` with one of its changes
turned off (``ours-X``) or a candidate it leaves out turned on (``ours+X``:
low-pass noise, predicted obstacle motion, the surface model of the cloud with
and without a larger check margin, the stall escape, the per-state broad phase,
the spheres' racing settings in every scenario: ``ours+race``; ``ours-route``
is ours without the route round the boxes after 30 steps without progress),
``release`` with ours's sampling,
and ``paper`` at ``ours``'s rollouts and horizon (the reference of the solver
time). Every variant runs the same
episodes (``scenarios.episode``, no recording): the cluttered scene for each of
``--links`` x ``--seeds`` controller seeds, and the dynamic spheres for
``--envs`` environments x ``--goals`` (controller seed ``--seed0``), 4 links. Printed per
variant and group (cluttered L4 / L5 / L7, spheres): episodes, success /
collision / stuck counts with 95% Wilson intervals of their rates, the median
reach step of the successes, and the solver time per MPPI step (mean +- std
over the steps of all its episodes), then per group the ratio of each
variant's mean solver time to ``paper``'s (same run, same rollouts and horizon).
Besides the named variants, ``PRESET:FIELD=VALUE[:FIELD=VALUE...]`` is a preset
with MPPIConfig fields changed (values: numbers, true, false, none or text).

``--timing STEPS`` measures the solver time alone, with less noise from other
work on the machine: for each group, every variant of ``--variants`` (``paper``
at ours's sizes) plans from the scene's start (straight robot) STEPS times,
against the cloud at the step's time (the obstacles move as in an episode, so
the convex model refits its moving clusters at every step), the variants in
turn, so all see the same load (``solver_time.solver_times``); printed: median
and mean +- std ms per step and the ratio of each median to ``paper``'s.
(Until 2026-11-30 every step saw the cloud at t = 0; until 2026-12-01
``--timing`` timed ``ours`` and ``paper`` whatever ``--variants`` named.)

On one NVIDIA H200 (jax 0.11.2), ``--timing 5 --variants
ours,ours-convex,paper --scenarios cluttered --links 4``: 18.4 / 5.0 / 4.5
ms, ours 4.1x the paper controller, 1.11x without the convex model;
``--timing 10 --variants ours,ours-sweep,ours-check,paper --scenarios
spheres``: 4.9 / 4.5 / 4.4 / 4.0 ms (1.22x).

Measured on a 2-core CPU machine shared with other work (default model, exact
judge). The first block is the earlier ``ours`` (no surface model, check
margin 0), ``--seeds 3 --envs 10``, spheres with the fixed goal:

  cluttered L4: ours 3/3 successes (median reach step 220), release 2/3 and 1
    collision, paper 0/3 (stuck); L5: ours 3/3 (46), release 1/3, paper 0/3;
    L7: all 3/3 (18). spheres: 9/10 successes and 1 collision for every
    controller, in environment 4, where a sphere sweeps through the first
    link's base: no configuration of that link stays clear of it at t = 1.4 s.
  ablation (cluttered L4 / L5, 3 seeds): without the release sampling 0/3 (2
    collisions) / 0/3; without the ESS temperature 0/3 / 3/3 (median 35);
    without the safety check the same episodes as ours (the check never
    changed an outcome here); low-pass noise (beta 0.6) 0/2 at L4; predicted
    obstacle motion on spheres: the same 9/10 with 25% more solver time.
  other seeds: L5 seed 3 collides at step 22 (predicted clearance 0.37 m,
    exact -0.003 m): the link grazes box 1's corner (2, 2.4, 6.5), whose nearest
    observed point is 0.52 m away. ``check_margin`` 0.15 alone changes nothing
    (the same four L5 episodes, seeds 0-3); 0.5 avoids the collision but
    leaves L4 stuck 1.5-1.6 m short (0/3).

The surface model (``fill_edge`` 1.2 m, ``ncedf.cloud``) and the check margin
0.15 m, cluttered L5 seeds 0-3 (``--links 5 --seeds 4 --variants
ours,ours+fill,ours+fill+margin``; the model then had no extrapolation): ours
3/4 and 1 collision (reach 41-184); fill alone 0/4, 4 collisions (-0.003 to
-0.034 m: the broad phase's 128 candidates per link cover a small patch of the
30x denser cloud, and the 0.05 m check margin is below the N-CEDF's and the
fill's errors); fill with 512 candidates 2/4, 2 collisions; fill and margin
0.15 4/4, no collision, reach 188-243, smallest exact distance 0.07-0.16 m
(with 512 candidates 184-214 and 0.12-0.21 m, but 2-3x the paper controller's
solver time). At 4 links the same fill and margin gave 4 collisions in 8
seeds (0-7, the robot climbs along box 1's face, where a hole of the fill
hides it by 0.28 m), and with the extrapolation into empty sectors 0/5
successes, 4 stuck 2.3-3.0 m short and 1 collision (seeds 1-5). So ``ours``
does not use the surface model: it trades the 5-link collision for 4-link
collisions and stalls.

A sharper temperature (``ours:target_ess=0.01``, 1% of N) frees the 4-link
runs that stall (seeds 4, 6, 7 reached at steps 212-215), but over 20 seeds
per link count (``scenarios.sweep`` with that preset) it collides more: L4
19/20 and 1 collision (seed 0, at a 0.8 m hole of box 1's cloud), L5 18/20
and 2 (seeds 3, 9), L7 18/20 and 2 (seeds 14, 17), against ours's 13/20 and
0, 19/20 and 1, 20/20 and 0. ``ours`` keeps 2%. The covariance 0.05 with
ours's sampling: seed 4 reached at step 181, seeds 6 and 7 collide.

Why the 4-link runs stall, and the stall escape. Every 4-link run is within
1.2 m of the goal by step 60 and then waits: sphere 0 sweeps through the
goal's corridor (x = 4, z = 3.8) at steps 70-130 and again from step 270,
sphere 1 rises under it at steps 130-200, and the last 0.8 m needs the body
within 0.3-0.4 m of box 2's top, where the collision cost balances the goal
cost. Successes come at steps 212-253, after sphere 1 goes down; the "stuck"
runs came as close as 0.41-0.55 m (tolerance 0.4) and were pushed 1.4 m away
by sphere 0's return. The stall escape (``MPPIConfig.stall_steps``: after 30
steps in which the best goal distance fell by less than 0.05 m, a sharper ESS
target until it falls again) on seeds 4-9 (``--links 4 --seed0 4 --seeds 6``;
ours: 2 of 6): ESS 1% 3 of 6, ESS 0.5% (``ours+stall``) 4 of 6, reach
217-251, no collision; predicted obstacle motion 2 of 6. Over seeds 0-16 (a
sweep with it in the preset) ``ours+stall`` had 12 successes (median reach
221), 4 stuck and 1 collision (ours: 10 successes, 7 stuck): seed 3 at step
112, dodging sphere 0 the tip dropped 0.3 m in one step onto box 2's top, predicted clearance 0.32 m, exact
-0.008 m (a hole of its cloud). So it is not part of ``ours``: the larger
steps that end the stalls find the holes of the sparse cloud (until the
convex model closed them; below).

A denser observation (``--density 16``, 16 points per m^2 of box face; the
paper's is 4). ``ours`` over 20 seeds per link count (``python -m
scenarios.sweep --scenario cluttered --links 4,5,7 --seeds 20 --option
density=16``): L4 1/20 (19 stuck 1.3-1.7 m short, holding 0.45-0.6 m from boxes
0 and 2), L5 14/20 and 6 collisions, L7 20/20 (median reach 19). The denser
cloud shows the robot its true clearance: at 4 points per m^2 the stuck and
successful 4-link runs held 0.25-0.38 m from the nearest observed point but
0.08-0.26 m from the true surface, so the sparse cloud's holes are what let it
through. The 5-link collisions come from the broad phase: its 128 candidates
per (step, link) around the rollouts' average cover a quarter of the area at
this density, and near the boxes 3-5% of the rollout distances are
over-estimated by more than 2 cm, by up to 1.2 m (``bench/broad_phase.py``).
With the per-state selection (``ours+state``), L5 seeds 0-9: 4 successes, 6
stuck, no collision (``ours``: 7 and 3 collisions); with 512 candidates per
(step, link), seeds 5-7: 2 successes, 1 stuck, no collision (``ours``: 3
collisions). At the paper's 4 points per m^2, ``ours+state`` over 20 seeds: L4
8/20 (12 stuck, median reach 243), L5 20/20 (median 44, no collision:
``ours`` collides with seed 3), L7 20/20 (18), at about twice ``ours``'s
solver time (L5 267 ms, L7 91 ms per step here). Weaker repulsion to let the 4-link robot through
(``ours:w_coll=0.4:w_coll_terminal=0.4``, seeds 0-3): 1 success (step 160) and
3 collisions; ``w_coll=0.6``: 1 success, 3 collisions. With
``check_margin=0.1`` as well (``ours:w_coll=0.4:w_coll_terminal=0.4:check_margin=0.1``)
at 16 points per m^2: L4 seeds 0-11 7 successes (median reach 158-164), 5
stuck, no collision; L5 seeds 0-5 6/6 (median 176); L7 6/6 (18). The same
variant at the paper's 4 points per m^2 (seeds 0-5): L4 6 collisions, L5 3
successes and 3 collisions. What a controller may dare depends on how well
its cloud covers the surfaces; no single setting here suits both densities.

Racing among the spheres (``ours`` there: ``MPPIConfig.update_unclipped`` and
``goal_reach``), ``--scenarios spheres --envs 200 --goals fixed,random``:
the release (clipped samples averaged, summed goal distances) pulls a
saturated plan back inside the rate bound at every step, so the robot
reaches the fixed goal at step 18-20 where the omniscient planner of
``bench/sphere_oracle.py`` reaches it at step 8 (the last links' third
chambers at 0.6 m/s throughout).

  variant (spheres)       fixed: success / collision, median reach   random: success / collision / stuck, median
  ours before (neither)   188 / 12, 20                               192 / 7 / 1, 21
  goal_reach only         190 / 10, 16                               194 / 4 / 2, 17
  update_unclipped only   193 / 7, 13                                194 / 6 / 0, 14
  both (``ours``)         195 / 5, 11                                196 / 4 / 0, 13

Of the 5 fixed-goal collisions, 4 (45, 53, 64, 93) have no motion the oracle
finds; 188 is hit at step 10, where the oracle reaches the goal at step 8.
Of the 4 random-goal ones, 53 has none; 75, 158 and 197 have. The same two
changes on the cluttered scene (``ours+race``, 20 seeds per link count):
4 links 3 successes and 17 collisions (at steps 4-16, down to -0.37 m: the
tip crosses a box face between its sparse points within one step), 5 links
6 and 14, 7 links 13 and 7; ``goal_reach`` alone 0 and 20, 1 and 19, 20 and
0 (a rollout swept through a box to touch the goal is charged only its
closest approach); ``update_unclipped`` alone 16 and 4 (median reach 44,
where ``ours`` needs 226), 15 and 5, 16 and 4, the collisions shallow (-0.002
to -0.078 m) at steps 10-65; with a 0.1 m check margin the same 13
collisions; with a 0.1 m safety margin 14 / 5 / 1 stuck (median 48), 18 /
1 / 1, 19 / 1 / 0; 0.2 m: 9 / 4 / 7, 12 / 4 / 4, 20 / 0 / 0. So ``ours``
races among the spheres only.

The convex model of the cloud (``MPPIConfig.convex_link``, ``ncedf.convex``:
each cluster of static points closed as a polytope, exact for the scene's
boxes; the robot's clearance to it bounded from below with 10 cover spheres
per link). All four collisions of the racing runs above (L7 seeds 12, 13, L5
12, 16: box 0; L4 1, 6: box 2) were a link inside a box face between its
points. With the model, racing and collision weights 0.4
(``ours:update_unclipped=true:convex_link=1.0:w_coll=0.4:w_coll_terminal=0.4``,
20 seeds per link count; the model then had static clusters only): L4 16
successes (median reach 162), 3 stuck and 1 collision (seed 3, sphere 0 runs
into the robot waiting near the goal), L5 20/20 (median 26), L7 20/20 (12).
With the release's collision weights the same model stalls the 4- and 5-link
robots near the boxes (L5 seeds 12, 16 stuck 1.8 / 2.6 m short, L4 seed 6
1.4 m; with w_coll 0.4 they reach the goal at steps 22, 25, 31). Moving
clusters modelled too (each sphere's 30 points as a polytope where it is
now), L4, 20 seeds: w_coll 0.4 17 successes (median 62), 2 stuck, 1
collision (seed 17, sphere 0 at t = 5.35 s); w_coll 0.2 14 successes (median
33), 4 stuck, 2 collisions. Each moving polytope then moved at its points'
observed velocity to the rollout state's time: L4 seed 17 stalls 1.24 m
short instead of colliding, seed 3 reaches the goal at step 275. That is
``ours`` in the cluttered scene; its 20-seed figures are in
``scenarios/presets.py``. Without the model (``--variants ours-convex
--scenarios cluttered --seeds 20``: racing and collision weights 0.4 on the
points alone) 4 links collide 20 times of 20, 5 links 16 (4 successes), 7
links 7 (13 successes). Its other two parts, seeds 0-9 (``--seeds 10
--variants ours-weights,ours-unclipped``), success / stuck and median reach,
none collided: without racing (``ours-unclipped``) L4 2 / 8 (210), L5 10 / 0
(40), L7 10 / 0 (20); with the release's collision weights 1.1
(``ours-weights``) L4 7 / 3 (185), L5 4 / 6 (148), L7 10 / 0 (14); ``ours``
on the same seeds L4 8 / 1 and 1 collision (115), L5 10 (24), L7 10 (12.5).

The stall escape again, now on top of the convex model (its reason to stay
out, a larger step into a hole of the cloud, is gone with the holes). The
convex model as above but with the faster ``ncedf.convex`` below (the same
model; other float rounding, so other episodes) and no stall escape
(``ours-stall``; ``python -m scenarios.sweep --scenario cluttered --links
4,5,7 --seeds 20`` with it in the preset): L4 17 successes (median reach
143), 3 stuck (seeds 0, 2, 10); L5 18 (median 26), 1 stuck (seed 13, 2.2 m
short), 1 collision (seed 19 at step 101: the robot waited ahead of sphere
0, in its direction of travel, and ran into it as it turned back); L7 20
(12). With the escape (``stall_steps`` 30, ``stall_ess`` 0.005; ``ours``):
L4 19 (median 147; seed 10 stuck), L5 20 (26.5; seed 13 at step 133, seed
19 at 143), L7 20 (12), no collision. Runs that never go 30 steps without
progress are unchanged (the same reach step): all of L7, L4 seeds 1, 8, 9,
12, 18 and 19, and L5 all but seeds 13 and 19.

A held last state (``ours+hold``, ``MPPIConfig.hold_time`` 1 s: each
rollout's last state also scored against the moving polytopes for one more
second, so the robot should not wait in an approaching sphere's path), with
the sweep above but without the escape, L4 seeds 0-10: 7 successes, 4 stuck
(``ours-stall`` on the same seeds: 8 and 3). Not measured further; not in a
preset.

``--timing 30`` with ``ours``'s convex model (its distance unrolled over the
clusters and planes, each cluster run by what it has: ``ncedf.convex``): L4
76.4 / 64.0 ms (1.19), L5 85.7 / 74.3 (1.15), L7 40.4 / 25.9 (1.56),
spheres 48.3 / 47.8 (1.01); with the first form of the model (reduced over
trailing cluster and plane axes), ``--timing 8``: L4 147 / 75 (1.97), L5 200
/ 93 (2.16), L7 93 / 32 (2.93). At 7 links (horizon 7) the model's share is
largest. Timed alone and interleaved (the jitted step, 30 rounds, median; a
one-off measurement on a scratch copy of ``ncedf.mppi`` with the parts
switched off, not a variant of this bench), the step takes 25.3 ms without
the model and 37.4 with it; 24.9 with the model in the safety check only,
35.5 in the rollouts only, 33.5 with the rollouts' 10 cover-sphere centres
per link (three sines or cosines each) replaced by a stand-in without
trigonometry. The fit on the host adds 2.3 ms.

The clusters are now a loop (``lax.fori_loop``, one copy of a cluster's code
in the program) and the safety check's candidates a ``lax.while_loop``: the
step lowers and compiles in about 18 s instead of 37 s (4 links), and
``python -m scenarios.cluttered --links 7`` takes 61 s instead of 87 s, the
same recording. ``--timing 10``, two runs each, interleaved: L4 1.13 and 1.23
(before 1.15 and 1.16), L7 1.31 and 1.34 (before 1.23 and 1.26).

The 7-link gap was the clearance's memory traffic. Timed inside the step (a
one-off scratch measurement, ``MPPI.step`` interleaved with ``paper``'s), the
step took 30.2, 31.5, 38.2, 39.1 and 42.1 ms with 1, 4, 8, 10 and 20 cover
spheres per link: a jump where one pass's arrays (800 x 7 x 7 x n floats)
outgrow the CPU's caches. ``ncedf.convex.robot_clearance`` now scores
``CLEARANCE_CHUNK`` (1024) states per pass, and the cover centres come from
``ncedf.robot.backbone_points`` (no angle phi, no per-point rotation). In
that scratch comparison: 40.9 ms before, 35.8 with the chunks alone, 31.8
with both (paper 26.2). ``--timing 30`` afterwards, with the kinematics
barrier of ``ncedf.mppi`` (same floats with 1 or 2 threads): L4 74.2 / 63.8
ms (1.16), L5 84.8 / 73.5 (1.15), L7 37.3 / 25.0 (1.49; 1.48 and 1.49 in two
more runs), spheres 47.3 / 45.9 (1.03); without the barrier L7 1.29-1.43
over four runs.
Chunks of 128, 512 and 2048 states gave 7-link ratios of 1.36, 1.34 and 1.29.
Again on 2026-12-01 (``--timing 20 --variants ours,paper --scenarios
cluttered --links 4,7``, the chunk set per run): 1024 states L4 1.18 and
1.15, L7 1.21 and 1.21; 4096 L4 1.16, L7 1.53; all 16000 in one pass L4
1.10, L7 1.73.
The new floats drew other episodes; with the stall escape off (``--variants
ours-stall --scenarios cluttered --links 4,5,7 --seeds 20``, before the
kinematics barrier of ``ncedf.mppi``): L4 16 successes (median 139), 3
stuck (seeds 2, 10, 15) and 1 collision (seed 13 at step 197, -0.040 m);
L5 19 (26) and 1 collision (seed 13 at step 289, -0.001 m); L7 20 (12).

The moving spheres as balls (``ncedf.convex.fit_sphere``: a cluster whose
points lie on a sphere is that sphere). As polytopes, each sphere's 30
points gave their bounding box, 0.3 m beyond the sphere at its corners,
cut by hull planes up to 0.1 m inside it: along a 4-link run (seed 3,
steps 150-276) the model's clearance to sphere 0 was 1.338 / 0.202 m where
the exact one was 1.478 / 0.105 m, and to sphere 1 0.378 m where it was
0.265 m; as balls 1.477, 0.093 and 0.238 m (the cover spheres' margin). The
4-link robot had stalled near the goal, where sphere 0 passes: 18 of 20
(median reach 137.5). With the balls (``python -m scenarios.sweep --scenario
cluttered --links 4,5,7 --seeds 20``): 20 / 20 / 20 (median 96 / 27 / 12),
no collision. The host's fit of the model now takes 0.44 ms per step (was
2.5): a group of points is fitted once (the static boxes), and a sphere
needs no hull. ``--timing 30`` with the cloud at t = 0 at every step (as
it was then): L4 71.5 / 62.8 ms (1.14), L5 83.6 / 72.8 (1.15), L7 35.5 /
29.8 (1.19), spheres 53.9 / 53.1 (1.02); with the cloud at each step's
time (``--timing`` since): L4 83.5 / 71.1 (1.17), L5 84.0 / 72.9 (1.15), L7
31.2 / 26.0 (1.20), spheres 48.3 / 48.1 (1.00). Within episodes
(``--variants ours,paper --scenarios cluttered --links 7 --seeds 10``) L7
30.7 / 24.0 ms (1.28), and the build before the balls and the fit cache
38.5 / 24.3 (1.59, 5 seeds), where ``--timing 30`` (cloud at t = 0) had
given it 1.49.
The stall escape with the balls (``--variants ours-stall --scenarios
cluttered --links 4,5,7 --seeds 20``): without it L4 18 successes (median
60) and 2 stuck, L5 20 (27), L7 20 (12), no collision; so it still frees
the 4-link robot in 2 of 20 seeds.

Among the dynamic spheres, two more changes (``ours-smooth``, ``ours-sweep``
turn them off). Where ``ours`` collided in the fixed-goal environment 188
(a sphere running into the first link at step 10), it slowed down in the
last 1.5 m to the goal (0.3 m per step against the oracle's 0.75), its
links' rates changing direction from step to step, while the oracle's
motion holds every rate near its bound throughout. Low-pass noise
(``noise_smoothing``) gives rollouts that keep a direction. Then random-goal
environment 99 collided: at step 4 the plan's first step swept a link
through a sphere's edge and out again (exact clearance -0.010 m halfway,
+0.18 m at its end state, the only state the rollouts scored), the safety
check refused it and every fallback but "no motion", and the robot stood
still for three steps while the sphere ran into it. ``sweep_first`` scores
each rollout's first state by the check's clearance over its step.
``--variants ours:noise_smoothing=B --scenarios spheres --envs 200 --goals
fixed,random`` (``--env0 200`` for environments 200-399, held out while
choosing beta), success / collision / stuck and median reach step:

  variant                 fixed 0-199    random 0-199   fixed 200-399  random 200-399
  ours before both        195 / 5, 11    196 / 4, 13    194 / 6, 11    191 / 7 / 2, 12
  beta 0.75               195 / 5, 10    195 / 5, 12
  beta 0.9                196 / 4, 10    195 / 4 / 1, 12  195 / 5, 10  192 / 7 / 1, 12
  beta 0.95               196 / 4, 10    195 / 4 / 1, 12
  beta 0.9 + sweep_first  195 / 5, 10    196 / 3 / 1, 12  195 / 5, 10  194 / 5 / 1, 12

(the "before" rows of 0-199 are the recorded Table III episodes, those of
200-399 the same sweep extended, ``python -m scenarios.sweep --scenario
spheres --envs 400``). The last row is ``ours``: over the 800 episodes 18
collisions instead of 22. The oracle (``bench/sphere_oracle.py --envs 200
--env0 200 --runs FOLDER``) finds no collision-free motion in 8 of the 400
fixed-goal environments (45, 53, 64, 93, 226, 294, 327, 399) and in 4 of the
400 random-goal ones (53, 274, 353, 376); ``ours`` collides in all of them,
and besides in fixed 188 and 340 (both a race against a sphere running into
the first link: the oracle reaches the goal at step 8 with 0.08 and 0.04 m
to spare, ``ours`` is 0.4-0.6 m short at step 9) and random 75, 158 (the
oracle's motion passes at 0.005 m), 245 and 340. The swept first step
scores 4 more states per rollout, with the broad phase's selection shared
by all samples as for the rollouts (``step_clearance(shared=True)``; per
sample, as for the check's few candidates, the same episodes at 1.8x the
solver time): ``--timing 30 --scenarios spheres`` 65.1 / 51.1 ms, 1.27x
the paper controller, and 60.7 / 46.3 ms, 1.31x, in a second run (1.00x
without it). Also tried, not kept: a goal cost blind within 0.15 m of the
goal (``ncedf.mppi`` scratch option), so the robot enters the success
radius at full speed: fixed 188 reached, no other episode of the 800
changed.

A refused plan as the warm start (``follow_executed``, among the spheres in
``ours``; ``ours-follow`` turns it off).
The random-goal environment 88, stuck before: at step 4 the plan's first
control was saturated towards sphere 7 (the robot nearly straight, where a
step of 0.015 m per chamber swings the tip by about 1 m), every one of the
1000 samples around it crossed the sphere within its first step (best swept
clearance 0.19 m to the centre, needed 0.75), so all their collision costs
sat at the ceiling, the goal cost ranked them, the update kept the plan, and
the check executed "no motion" for the remaining 196 steps. Warm-started
from the executed fallback instead, the robot moves off at step 5 and reaches
the goal at step 16. ``--variants ours --scenarios spheres --envs 200
--goals fixed,random`` (and ``--env0 200``), success / collision / stuck:

  variant        fixed 0-199   random 0-199   fixed 200-399   random 200-399
  without it     195 / 5 / 0   196 / 3 / 1    195 / 5 / 0     194 / 5 / 1
  with it        195 / 5 / 0   197 / 3 / 0    195 / 5 / 0     195 / 4 / 1

the same fixed-goal collisions; random 88 and 245 reached (245 collided
before); the random 200-399 stuck episode (271: the goal at z = -0.17 m, 6 m
out, behind spheres that push the robot back and forth) is not this stall.
In the cluttered scene (``--variants ours:follow_executed=true --scenarios
cluttered --seeds 20``): 20 / 20 / 20 successes, no collision, median reach
73 / 30 / 12 (``ours`` 96 / 27 / 12), smallest exact clearance 0.066 / 0.064
/ 0.141 m; ``ours`` leaves it off there, so the Table IV episodes repeat.
Another controller seed (``--seed0 1``, the same 200 environments per goal
kind): fixed goal 196 / 4 / 0, the 4 collisions exactly the environments
where the oracle finds no motion (45, 53, 64, 93); random goals 196 / 4 / 0
(25, 53, 75, 158); median reach 11 and 12 steps.

Predicted sphere motion on top of ``ours`` (``ours+motion``: the rollouts see
each observed centre moved at its velocity from the last two observations;
2026-12-02, ``--variants ours+motion --scenarios spheres --envs 200 --goals
fixed,random``, beside ``--variants ours`` in the same session): fixed goal
194 / 6 / 0 (ours 195 / 5 / 0), random goals 196 / 4 / 0 (ours 197 / 3 / 0),
median reach 10 and 12 either way. It collided where ``ours`` did and in
fixed 25 and random 72 besides. Random 75, where ``ours`` collides at step
26 (its goal 6.8 m out at z = 0.7 m; a sphere runs at the first link above
the base while the robot, stretched towards the goal, holds on), collided at
step 28 with it. Not kept.

``--timing 8`` with the surface model: L4 131.4 / 111.1 ms (1.18), L7 58.5 /
41.2 (1.42), spheres 84.3 / 80.8 (1.04) (before it: L4 64.8 / 62.8 (1.03),
L5 147.8 / 136.3 (1.08), L7 47.8 / 47.9 (1.00), spheres 87.4 / 85.1 (1.03),
``--timing 30`` on a quieter machine).

One process, episodes in sequence (a configuration compiles once). ``--json``
also writes every episode's result. Ctrl-C prints the table of the episodes
finished so far and exits 130.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ncedf.mppi import MPPI, MPPIConfig
from recorder.cli import EXIT_STATUS, Stopped, exit_with, stop_on_signals
from scenarios.episode import Episode, EpisodeSettings, option_positive
from scenarios.presets import PRESETS

from arguments import parse_list, positive
from solver_time import solver_times

#: name -> (preset, MPPIConfig fields changed). ``paper`` also takes ``ours``'s sizes (see ``make_episode``).
VARIANTS: dict[str, tuple[str, dict]] = {
    "release": ("release", {}),
    "release+sampling": ("release", {"sampling": "release"}),
    "ours": ("ours", {}),
    "ours-sampling": ("ours", {"sampling": "project"}),
    "ours-ess": ("ours", {"target_ess": None}),
    "ours-check": ("ours", {"safety_check": False}),
    "ours+fill": ("ours", {"fill_edge": 1.2}),
    "ours+fill+margin": ("ours", {"fill_edge": 1.2, "check_margin": 0.15}),
    "ours+smooth": ("ours", {"noise_smoothing": 0.6}),
    "ours-smooth": ("ours", {"noise_smoothing": 0.0}),
    "ours-sweep": ("ours", {"sweep_first": False}),
    "ours+motion": ("ours", {"predict_motion": True}),
    "ours-stall": ("ours", {"stall_steps": 0}),
    "ours+state": ("ours", {"selection": "state"}),
    "ours-unclipped": ("ours", {"update_unclipped": False}),
    "ours-reach": ("ours", {"goal_reach": False}),
    "ours+race": ("ours", {"update_unclipped": True, "goal_reach": True}),
    "ours-convex": ("ours", {"convex_link": 0.0, "route_after": 0}),  # the route avoids the convex model
    "ours-weights": ("ours", {"w_coll": 1.1, "w_coll_terminal": 1.1}),
    "ours+hold": ("ours", {"hold_time": 1.0}),
    "ours-follow": ("ours", {"follow_executed": False}),
    "ours-route": ("ours", {"route_after": 0}),
    "paper": ("paper", {}),
}
#: z for a 95% interval.
Z95 = 1.959963984540054
QUICK = {"links": "4,5,7", "seeds": 1, "envs": 2, "variants": "ours,paper", "max_steps": 60}


def parse_value(text: str):
    """A field value from the command line: none, true, false, an int, a float, or the text."""
    lowered = text.lower()
    if lowered in ("none", "true", "false"):
        return {"none": None, "true": True, "false": False}[lowered]
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def resolve(variant: str) -> tuple[str, dict]:
    """(preset, changed fields) of a named variant or of ``PRESET:FIELD=VALUE:...``."""
    if variant in VARIANTS:
        return VARIANTS[variant]
    preset, *pairs = variant.split(":")
    if preset not in PRESETS or not pairs or any("=" not in pair for pair in pairs):
        raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)} "
                         "or PRESET:FIELD=VALUE[:...]")
    fields = {}
    for pair in pairs:
        name, value = pair.split("=", 1)
        if name not in {f.name for f in dataclasses.fields(MPPIConfig)}:
            raise ValueError(f"unknown MPPIConfig field {name!r} in variant {variant!r}")
        fields[name] = parse_value(value)
    return preset, fields


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a rate k / n (n > 0)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def episodes(args) -> list[tuple[str, EpisodeSettings]]:
    """(group, settings) of every episode a variant runs (controller filled in per variant)."""
    out = []
    options = (("density", str(args.density)),) if args.density else ()
    if "cluttered" in args.scenarios:
        for links in args.links:
            for seed in range(args.seed0, args.seed0 + args.seeds):
                out.append((f"cluttered L{links}", EpisodeSettings("cluttered", links, seed,
                                                                   max_steps=args.max_steps, options=options)))
    if "spheres" in args.scenarios:
        for goal in args.goals:
            for env in range(args.env0, args.env0 + args.envs):
                out.append((f"spheres {goal}", EpisodeSettings("spheres", 4, args.seed0, env_seed=env, goal=goal,
                                                               max_steps=args.max_steps)))
    return out


def make_episode(variant: str, settings: EpisodeSettings) -> Episode:
    """The prepared episode of ``variant`` (``paper`` at ours's rollouts and horizon)."""
    preset, fields = resolve(variant)
    if preset == "paper":
        samples, horizon = PRESETS["ours"].sizes(settings.scenario, settings.links)
        settings = dataclasses.replace(settings, samples=samples, horizon=horizon)
    episode = Episode(dataclasses.replace(settings, controller=preset))
    if fields:
        config = dataclasses.replace(episode.scene.config, **fields)
        if "safety_margin" in fields:  # keep the scene's extra (sphere radius)
            extra = episode.scene.world.margin_extra
            config = dataclasses.replace(config, safety_margin=fields["safety_margin"] + extra)
        episode.scene = dataclasses.replace(episode.scene, config=config)
        episode.mppi = MPPI(episode.scene.spec, episode.shape, config)
    return episode


def run_one(variant: str, settings: EpisodeSettings):
    """One episode of ``variant`` (no recording): its EpisodeResult."""
    return make_episode(variant, settings).run(out=None)


def timing_table(args) -> str:
    """``--timing``: one line per group and variant (see the module docstring)."""
    lines = [f"{'group':<16}{'variant':<18}{'N':>6}{'H':>4}{'median ms':>11}{'mean +- std ms':>19}{'/paper':>8}"]
    seen = set()
    for group, settings in episodes(args):
        if group in seen:
            continue
        seen.add(group)
        prepared = {v: make_episode(v, settings) for v in args.variants}
        t = solver_times(prepared, args.timing)
        paper_median = np.median(t["paper"]) if "paper" in t else None
        for v, episode in prepared.items():
            med = np.median(t[v])
            ratio = f"{med / paper_median:>8.2f}" if paper_median else f"{'-':>8}"
            lines.append(f"{group:<16}{v:<18}{episode.scene.config.samples:>6}{episode.scene.config.horizon:>4}"
                         f"{med:>11.1f}{t[v].mean():>11.1f} +- {t[v].std():<5.1f}{ratio}")
    return "\n".join(lines)


def summarise(rows: list[dict]) -> str:
    """The table of results (see the module docstring)."""
    groups = defaultdict(list)
    for row in rows:
        groups[(row["group"], row["variant"])].append(row)
    paper_ms = {g: np.mean([r["ms_mean"] for r in rs]) for (g, v), rs in groups.items() if v == "paper"}
    lines = [f"{'group':<16}{'variant':<18}{'n':>4}  {'success [95% CI]':<22}{'collision [95% CI]':<22}"
             f"{'stuck':>6}{'reach med':>10}{'solver ms':>18}{'/paper':>8}"]
    for (group, variant), rs in sorted(groups.items()):
        n = len(rs)
        counts = {o: sum(r["outcome"] == o for r in rs) for o in ("success", "collision", "stuck")}
        cell = {o: "{:>2} ({:.2f}-{:.2f})".format(counts[o], *wilson(counts[o], n)) for o in counts}
        reach = [r["reach_step"] for r in rs if r["reach_step"] is not None]
        med = f"{np.median(reach):.0f}" if reach else "-"
        means = np.array([r["ms_mean"] for r in rs])
        weights = np.array([r["steps"] for r in rs], float)
        mean = float(np.average(means, weights=weights))
        var = float(np.average(np.array([r["ms_std"] for r in rs]) ** 2 + (means - mean) ** 2, weights=weights))
        ratio = f"{np.mean(means) / paper_ms[group]:.2f}" if group in paper_ms else "-"
        lines.append(f"{group:<16}{variant:<18}{n:>4}  {cell['success']:<22}{cell['collision']:<22}"
                     f"{counts['stuck']:>6}{med:>10}{mean:>10.1f} +- {math.sqrt(var):<5.1f}{ratio:>8}")
    return "\n".join(lines)


def parse_variants(text: str) -> list[str]:
    values = parse_list(text, str, "variant")
    for value in values:
        try:
            resolve(value)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return values


def episodes_config_check(variant: str, scenario: str) -> None:
    """Raise ValueError naming a bad field value: MPPIConfig's own validation of the preset's
    fields in ``scenario`` with the variant's changed (some need a scenario's fields, e.g. the
    route the cluttered scene's convex model)."""
    preset, fields = resolve(variant)
    try:
        MPPIConfig(**{**PRESETS[preset].fields_for(scenario), **fields})
    except ValueError as exc:
        raise ValueError(f"variant {variant!r} in the {scenario} scene: {exc}") from None


def density_arg(text: str) -> float:
    try:
        return option_positive("density", text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", default="release,ours,paper",
                   type=parse_variants,
                   help=f"comma-separated, from: {', '.join(VARIANTS)}, or PRESET:FIELD=VALUE[:...] "
                        "(default release,ours,paper)")
    p.add_argument("--scenarios", default="cluttered,spheres",
                   type=lambda t: parse_list(t, str, "scenario", ("cluttered", "spheres")))
    p.add_argument("--links", default="4,5,7", type=lambda t: parse_list(t, int, "links", above_zero=True),
                   help="cluttered link counts (default 4,5,7)")
    p.add_argument("--seeds", type=positive, default=3, help="cluttered controller seeds per link count (default 3)")
    p.add_argument("--seed0", type=int, default=0,
                   help="first controller seed; the spheres' episodes use this one (default 0)")
    p.add_argument("--density", type=density_arg,
                   help="cluttered: observed points per m^2 of box face (default: the paper's 4)")
    p.add_argument("--envs", type=positive, default=10, help="spheres environments per goal kind (default 10)")
    p.add_argument("--env0", type=int, default=0, help="first spheres environment (default 0)")
    p.add_argument("--goals", default="fixed", type=lambda t: parse_list(t, str, "goal", ("fixed", "random")),
                   help="spheres goal kinds (default fixed)")
    p.add_argument("--max-steps", type=positive, help="override every scenario's step budget")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 1 seed, 2 environments, ours and paper, 60 steps")
    p.add_argument("--timing", type=positive, metavar="STEPS",
                   help="instead of episodes: solver ms of each variant and its ratio to paper, STEPS steps per group")
    p.add_argument("--json", type=Path, help="also write every episode's result here")
    args = p.parse_args(argv)
    if args.quick:
        args.links, args.seeds, args.envs = [4, 5, 7], QUICK["seeds"], QUICK["envs"]
        args.variants, args.max_steps = QUICK["variants"].split(","), QUICK["max_steps"]
    for variant in args.variants:
        for scenario in args.scenarios:
            try:
                episodes_config_check(variant, scenario)
            except ValueError as exc:
                p.error(str(exc))
    if "paper" not in args.variants:
        print("note: without the paper variant there is no solver-time ratio", file=sys.stderr)

    if args.timing:
        try:
            with stop_on_signals():
                print(timing_table(args))
        except Stopped as stop:
            print(f"interrupted ({stop}): no timing table", file=sys.stderr)
            return EXIT_STATUS[stop.signum]
        return 0
    rows = []
    todo = [(v, g, s) for v in args.variants for g, s in episodes(args)]
    start = time.perf_counter()
    try:
        with stop_on_signals():
            for variant, group, settings in tqdm(todo, desc="episodes", file=sys.stderr, dynamic_ncols=True):
                r = run_one(variant, settings)
                rows.append({"variant": variant, "group": group, "links": settings.links, "seed": settings.seed,
                             "env_seed": settings.env_seed, "outcome": r.outcome, "reach_step": r.reach_step,
                             "steps": r.steps, "min_true_distance": r.min_true_distance,
                             "final_goal_distance": r.final_goal_distance, "ms_mean": r.solver_ms_mean,
                             "ms_std": r.solver_ms_std})
    except Stopped as stop:
        print(f"interrupted ({stop}): {len(rows)} of {len(todo)} episodes finished; their table follows",
              file=sys.stderr)
        if rows:
            print(summarise(rows))
        return EXIT_STATUS[stop.signum]
    print(summarise(rows))
    print(f"{len(rows)} episodes in {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    exit_with(main())
