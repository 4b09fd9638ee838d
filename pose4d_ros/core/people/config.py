"""How people are told apart over time: `TrackingConfig`, the parameters of the association,
the tracks' lifetimes and the detector slots (the design: the package's docstring,
`core.people`)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class TrackingConfig:
    """How people are told apart over time (module docstring).

    max_people : candidates searched per frame at most (the best first); the rest are counted.
    confirm_frames : frames a new track must be matched before it is published, while another
        confirmed track exists.
    max_unseen_s : a confirmed track unseen longer than this ends, seconds.
    max_hidden_s : the same for a track held behind a nearer person (`max_held_s`): a person
        who walks behind another and stops there is out of sight for longer than one who just
        leaves the detector for a moment, and came back under a new id after `max_unseen_s`.
        Chosen on validation (`pose4d eval DIR --model rgbd_14 --no-single-frame --config
        tracking.max_hidden_s=S`; average7 / MOTA / IDF1 / id switches per 1000 person-frames;
        false skeletons per 1000 frames the same at every value): at 1 s (`max_unseen_s`, the
        tracker before) `valid60_people2` 88.38 / 0.959 / 0.972 / 0.69, `valid60_people3`
        86.49 / 0.962 / 0.975 / 0.46, `valid30_people2b` 86.14 / 0.913 / 0.955 / 0; at 1.5, 2
        and 3 s alike 88.64 / 0.963 / 0.981 / 0, 86.78 / 0.971 / 0.985 / 0 and 86.26 / 0.915 /
        0.956 / 0 (2 s shipped, the middle of the plateau); the alone twins cannot change
        (nobody to be behind). The sweep `hidden` of `make results`.
    torso_std_m : standard deviation of a torso point's position besides the covariances,
        metres (the torso point moves within the body as arms and legs do).
    max_speed_mps : how fast an unseen person may have gone, metres a second (the spread of an
        unseen track's position grows with it).
    gate_chi2 : largest squared Mahalanobis distance of an assigned pair (3 degrees of freedom).
    max_gap_s : a gap between two frames longer than this (or a stamp going back) ends every
        track, seconds: `SlqeConfig.max_dt_s`, after which each SLQE restarts anyway.
    birth_score : while another track is confirmed, a detection starts or grows a tentative
        track only when its part model score (`JointSet.score`, the SVM's: 0 is its boundary)
        is at least this; a confirmed track takes any. A region that passes the person-size
        rules but is no person (a door jamb at the image's edge) scores low, and does not
        become a second person.
    trust_score : with no track confirmed, every detection scoring at least this is confirmed
        at its first frame (two people in view at a stream's start are both published from
        it); when none does, the foreground's best region is, as the single-person tracker
        trusts its one detection. A chair nearer and larger than the person (the foreground's
        best region) scores under it, the person over it (part model scores on validation:
        people 7-9 at the 5th percentile, 12 at the median; other regions at most 6.1).
    hold_occluded : a track's detected joints that lie on a nearer person's body (within
        `occluded_width_m` of one of their bones in the image, at their depth) are not
        measured: the track keeps its last estimate of them (TRACKED), as it keeps the whole
        pose of a person hidden behind another. What the part model puts there is a guess
        (the person's own pixels are not seen), and it pulls the skeleton onto the nearer
        person. On validation (`valid60_people2`, the detections of the shipped settings),
        average7 86.59 without, 87.36 / 87.47 / 87.23 / 88.43 with widths 0.06 / 0.09 / 0.12
        / 0.22 m (0.16 m and more lose MOTA: 0.953 -> 0.912-0.917); `valid30_people2`
        unchanged (81.02: its hidden people are never tracked). On, 0.09 m.
    quiet_frames : a candidate region whose last search scored under `birth_score` (a region
        that cannot start a track: a door jamb or a wall's edge at the image's border, a
        cabinet) and has not moved since (its pixels those of then up to `STILL_IOU`, its
        depth within `STILL_M`) keeps that detection for up to
        this many frames before it is searched again (0: every candidate searched every
        frame). Such regions cost the detector a full search each frame; a person's region
        scores over it, or moves.
    max_held_s : a person hidden behind another is published at their last pose (held, every
        joint TRACKED) for at most this long, then their track is kept unpublished until they
        are seen again (same id) or it ends (`max_hidden_s`); inf (the default): held until
        then. A pose held long is often where nobody is (the person moves on behind the
        other), but not limiting it was chosen on validation by the criterion of the settings
        above, mean MOTA (`pose4d eval DIR --model rgbd_14 --max-people 4 --config
        tracking.max_held_s=S`; average7 / MOTA / IDF1 / false skeletons per 1000 frames):
        `valid60_people2` 87.57 / 0.951 / 0.959 / 8.3 unlimited, 87.42 / 0.939 / 0.947 / 0 at
        0.65 s; a three-person set of an earlier stop (seed not recorded) 87.12 / 0.954 /
        0.977 / 9.7 and 86.92 / 0.950 / 0.972 / 0; the alone twins unchanged. (0.65 s was
        shipped for a while for its false skeletons; on the held-out sets it removed none and
        cost average7 0.3-1.2: docs/NOTES.md.)

    detector_keep_s : how long a person's detector state (`PeopleDetector`: their person scale,
        the arm prior) is kept unseen, seconds; 0 (the default): as long as their track can
        be, the longer of `max_unseen_s` and `max_hidden_s`. The detector node, which does not
        read the tracker's parameters, sets it (`detector.keep_unseen_s`) to follow a tracker
        whose lifetimes were changed.
    confirmed_first : the confirmed tracks take their detections first, the tentative ones
        share what is left. In one assignment, a track started the frame before beside a
        confirmed one (a detection that jumped out of the confirmed track's gate for a frame)
        took that person's detection whenever it was nearer, and the confirmed track went on
        unseen, predicted where nobody was, for up to `max_unseen_s`: a false skeleton every
        frame. Chosen on validation (`pose4d eval DIR --model rgbd_14 --max-people 4 --config
        tracking.confirmed_first=false`, average7 / MOTA / IDF1 / false skeletons per 1000
        frames): `valid60_people2` 87.6 / 0.951 / 0.959 / 8.3 without, 87.9 / 0.956 / 0.964 /
        0 with; `valid60_people3` (three people, s01-s06, seed 203) 86.6 / 0.943 / 0.954 /
        48.6 and 86.6 / 0.959 / 0.971 / 0.
    max_unseen_at_side_s : a confirmed track unseen longer than this (not held behind
        someone) whose pose reaches `SIDE_SHARE` of the image's width from its left or right
        edge is kept but not published: most often its person has walked out of the image, and
        it is a ghost at the border for `max_unseen_s` (inf: published). On the real lab_walk
        (after `tentative_margin`, whose new ghosts were such tracks) ghosts 16 -> 8, people
        found 148 -> 144 of 228, agreement 69.4 % the same; at 0.15 s (lab_walk's first unseen
        frame, 0.1 s, published) 11 and 146. Guard (`rgbd_kf_ik` average7): `valid60_people3b`
        91.41 -> 91.22 (MOTA 0.982 -> 0.977 at 0 s; rendered people beside the image's side
        unseen a frame or two, hence the 0.07 s), `valid60_people3b_high` 85.43 -> 85.40,
        `valid60_people2`, `valid30`, `valid30_msr`, `valid30_near`, `valid30_high` the same.
        (Ending such tracks at once, tried before, cost the renders returning people's ids.)
    tentative_margin : a confirmed track does not take a detection first that a tentative
        track fits better by more than this (squared Mahalanobis distance; inf: always
        first). On the real lab_walk a man who walked out of the image left his track within
        the gate of the man who walked in behind him (cost 15.3 of 16), whose own track
        (cost 1.1) then lost his detection every frame: never confirmed. Chosen on lab_walk
        (agree@0.1 62.8 -> 69.4 %, people found 145 -> 148 of 228, 11 -> 16 ghosts: the
        track of a person who left is now unseen at the border for its `max_unseen_s`, where
        it went on in someone else's detection before); 1, 3, 6 and 9 alike, 12 half as good;
        guard: `valid60_people2` the same, `valid60_people3b` 91.29 -> 91.41 (IDF1 0.989 ->
        0.991), `valid60_people3b_high` 85.41 -> 85.43 (0.983 -> 0.979); 9 kept, the nearest
        to confirmed first.
    held_continues : a track held behind a nearer person takes a detection only where they
        come out: its torso pixel in that person's box (grown by a tenth of its height),
        whatever its score (a person coming out from behind another is partly seen and scores
        low; without it their track ended unseen and they came back under a new id), and
        nowhere else, whatever its score: the held track's gate, grown with the time unseen
        (`max_speed_mps`), reaches metres after half a second, and a wall's edge at the
        image's border (first seen on the held-out `test30_people2`, then on a new validation
        set, `valid30_people2b`: s01-s06, seed 99, 24 videos of two people) or clutter
        scoring over `birth_score` beside the pair was taken for the hidden person. False:
        a held track takes what any track unseen beside another person takes (a detection
        scoring `birth_score`, anywhere in its gate). On validation, with `confirmed_first`
        (`--config tracking.held_continues=false`; average7 / MOTA / IDF1 / false skeletons
        per 1000 frames): `valid60_people2` 87.9 / 0.956 / 0.964 / 0 without, 88.1 / 0.958 /
        0.972 / 0 with (id switches per 1000 person-frames 1.4 -> 0.7); `valid60_people3`
        86.6 / 0.959 / 0.971 / 0 and 86.5 / 0.962 / 0.975 / 0 (0.9 -> 0.5);
        `valid30_people2b` 86.0 / 0.901 / 0.948 / 22.2 and 86.1 / 0.912 / 0.954 / 13.0; the
        alone twins unchanged. (Its earlier forms on valid30_people2b: taking any detection in
        the gate 85.6 / 0.894 / 0.945 / 33.3; emerging low-scoring ones and birth-scoring ones
        anywhere 85.8 / 0.902 / 0.949 / 22.2, the other sets as now.)
    held_own_front : a track held behind a nearer person takes a detection coming out
        (`held_continues`) only from behind that person (`_Track.behind`, the track it was
        held behind), not from behind another: a wall's edge behind a third person, in the
        held track's gate (grown with the time unseen), was taken for the hidden person, a
        false skeleton for 35 frames (on `valid60_people3d`, one of two new validation sets of
        36 three-person videos each: s01-s06, seeds 207, `valid60_people3c`, and 209). False:
        from behind any nearer person (the tracker before). On validation (`pose4d eval DIR --model
        rgbd_14 --no-single-frame --config tracking.held_own_front=false`; average7 / MOTA /
        false skeletons per 1000 frames): `valid60_people3d` 86.72 / 0.950 / 16.2 without,
        87.00 / 0.960 / 0 with; `valid60_people2`, `valid60_people3`, `valid30_people2b`,
        `valid60_people3b` and `valid60_people3c` the same frames with and without. The sweep
        `held_front` of `make results`.
    held_needs_front : a track is held only while a person seen this frame stands in front of
        it (`_behind`); when nobody does, its person is not hidden but unseen, and ends as
        any unseen track (after `max_unseen_s`). False: held until seen or `max_hidden_s`
        (the tracker before). On the real development recording lab_walk (10 fps), a desk's
        end at the image's border taken for a person stayed held for 17 frames after the
        person who had passed in front of it had left. On validation (`valid30`,
        `valid30_msr`, `valid60_people2`, `valid60_people3`, `valid30_high`,
        `valid60_people3_high`) the same to the digit with and without.
    emerging_score : while another track is confirmed, a detection coming out from behind a
        nearer person (its torso pixel in the box of a confirmed track's detection nearer by
        over `torso_std_m`, `_emerging`) starts or grows a tentative track from this score
        instead of `birth_score`. Partly seen, a person coming out scores under the birth
        score for many frames, and then flickers about it: a tentative track must be matched
        every frame, and `confirm_frames` in a row came late (on the validation set
        `valid60_people3b`, a person half seen from frame 43 scored 3.4-5.3 and was born at
        frame 58). Only a detection clear of the image's sides (`_clear_of_sides`): behind a
        person near the side, a wall's edge cut by the border scored 3.5-4 and became a
        person. Chosen on validation (`pose4d eval DIR --model rgbd_14 --no-single-frame
        --config tracking.emerging_score=S`; average7 / MOTA / false skeletons per 1000
        frames): 5 (`birth_score`, the tracker before) `valid60_people3b` (three people,
        s01-s06, seed 205, 24 videos) 89.35 / 0.958 / 0, `valid30_people2b` 86.45 / 0.916 /
        0, `valid60_people2` 89.13 / 0.964 / 0; 3: 89.82 / 0.972 / 0, 87.06 / 0.930 / 0,
        89.20 / 0.965 / 0; `valid60_people3` 87.13 / 0.971 / 0 at both; 2 as 3; 3 and 3.5
        without the side rule 37.5 and 56.9 false skeletons per 1000 frames on
        `valid60_people3b` and `valid60_people3`. The sweep `emerging` of `make results`.
        A person too near to be seen whole, cut by the image's bottom edge (a located joint
        at or below the depth image's last row of readings), is partly seen too, and born
        from this score as well (`PeopleTracker._partly_seen`): on the real lab_walk their
        regions score median 5.2 where the furniture cut by that edge scores -0.9 (found 140
        -> 155 of 228, ghosts 20 both); the validation renders the same to the digit.
    free_space_m, free_share : an unseen confirmed track (in the open or held behind someone)
        ends when the depth image shows nobody where it puts the person (`free_space`): at
        least `free_share` of the readings in a torso-sized square around its torso point lie
        over `free_space_m` beyond it, or the point projects outside the image (0: off, the
        tracker before; also off without a depth image). On real recordings a person who
        walked off was predicted on for `max_unseen_s` (out through the image's side, or held
        where they had stood for `max_hidden_s`), a ghost skeleton every frame. On the real
        development recording lab_walk (`pose4d eval ../shared/data/real/lab_walk --fps 10
        --labels labels/real/lab_walk.json [--colour-net lspet_convnet] --config
        tracking.free_space_m=M`; ghosts, labelled people found of 228): off 276, 160 (with the
        network 94, 159); 0.75 m with a share of 0.9 174, 154 (82, 152); 1.5 m and 0.9 209,
        167 (78, 157), shipped: the farthest, the surest the person is gone. Validation renders
        (`valid60_people2`, `valid60_people3b`, `valid60_people3d`, `valid30_people2b`): the
        same to the digit with it as without.
    same_person_m : an unseen confirmed track (in the open or held) ends when its person is
        one seen this frame under another id: its torso pixel in the box of a confirmed track
        seen this frame and its torso within this depth of theirs, metres. 0: off. On the real
        development recording lab_walk, a person lost for a frame came back as a new track
        while their old one coasted on them, or was held a little behind the new one (0.2 m):
        two skeletons on one person, a ghost (`pose4d eval ../shared/data/real/lab_walk --fps
        10 --labels labels/real/lab_walk.json --config tracking.same_person_m=M`; ghosts /
        labelled people found of 228 with the network: off 46 / 139, 0.15 m 36 / 138, 0.3 m
        30 / 138, 0.5 m 23 / 136). On validation (`pose4d eval DIR --no-single-frame --config
        tracking.same_person_m=M`; `rgbd_kf_ik` average7 / MOTA / false skeletons per 1000
        frames, off, 0.3 and 0.5 m): `valid60_people2` 87.60 / 0.895 / 102.8 at off and 0.3,
        87.45 / 0.892 / 102.8 at 0.5; `valid60_people3b` 89.65 / 0.966 / 36.8, 89.65 / 0.969 /
        27.8, 89.61 / 0.969 / 27.8; `valid60_people3d` 85.59 / 0.972 / 1.4, 85.57 /
        0.971 / 0 at 0.3 and 0.5; `valid60_people3`, `valid30_people2b`
        the same at every value. 0.3 m shipped (0.5 costs validation points).
    max_span_m : a track whose located joints lie farther apart than this in 3-D is kept but
        not published (no person's body spans it: a 2 m person's wrist raised above the head
        is some 2.4 m from their ankle). On the real development recording lab_walk a track
        coasting after its person had left put its predicted joints metres apart across the
        empty floor, a ghost every frame; on validation renders no published skeleton spans
        over 1.86 m (`valid60_people2`, 1396 skeletons), on lab_walk 9 of 151 over 2.5 m.
    one_body_m : a track whose torso lies below the torso of a skeleton published before it
        (the longer tracked first, `_ordered`) in the image, no nearer the camera, within this
        distance of that skeleton's body axis in 3-D (the line through its hips and shoulders)
        and at most `tracker.LEGS_M` (1.3 m) below its hips along it (`tracker.axis_position`)
        is kept but not published: a piece of that person's body. Seen from above, a person's
        legs lie deeper than their torso and may be a region of their own, with a skeleton of
        its own 0.4-1.4 m below theirs but on their axis. The rule first measured the distance
        between the two torsos (`valid60_people3b_high`: 72.2 false skeletons per 1000 frames,
        pieces over 0.6 m below), then asked for the piece's torso in the other's box (its
        feet, below the skeleton's ankles, went through: `valid60_people3c_high` 12.5). 0: off.
        Chosen on validation (`pose4d eval DIR --no-single-frame --config
        tracking.one_body_m=M`; `rgbd_kf_ik` average7 / MOTA / false skeletons per 1000 frames
        on `valid60_people3_high`, `valid60_people3b_high`, `valid60_people3c_high`): 0.5
        84.53 / 0.930 / 2.8, 84.98 / 0.969 / 5.6, 82.98 / 0.951 / 4.9; 0.6 84.51 / 0.928 /
        2.8, 84.98 / 0.970 / 2.1, the same; 0.7 as 0.6 but 0.971 / 0 on the second (with the
        box test also 0.4: 18.8 on the second, and 0.8: `valid60_people2` 89.08 -> 89.04).
        Within a tie of each other: 0.6 kept. `valid30`, `valid30_msr`, `valid30_high`,
        `valid60_people2`, `valid60_people3` the same to the digit as with the rule before; the
        real development recordings too (lab_walk: 148 of 228 people found; without the image
        and depth tests a person standing just behind another's legs was taken for them, 145).
    min_span_m : a track whose located joints all lie within this distance of each other in
        3-D is kept but not published: smaller than any person (seen from above, a person's
        feet found as a region, and a skeleton, of their own; before the camera's
        calibration has come, without 3-D, none is judged; the one-person path,
        `core.pipeline.ONE_PERSON`, publishes its person whatever the size). Chosen on
        validation (`--config tracking.min_span_m=M`): off, 0.3, 0.5 and 0.7 give every
        validation set the same average7; `valid60_people3c_high` 22.2 false skeletons per
        1000 frames off, 12.5 at 0.3 and 0.5 (MOTA 0.946 -> 0.949), at 0.7 a person-frame
        lost; the validation sets' people span at least 0.58 m (`valid60_people3b_high`),
        lab_walk's 0.97 m (two of its ghosts under 0.3 m).
    max_shoulders_m : a track whose shoulders have lain farther apart than this in 3-D, the
        median over every frame it was published or kept in, is kept but not published: no
        person's shoulders are 0.9 m apart (0: off; before the camera's calibration has
        come, without 3-D, none is judged; the one-person path publishes its person
        whatever). On lab_walk a track on a monitor and the chair beside it, after its person
        had left, had its shoulders 1.02-1.05 m apart for its four frames, its real people's
        tracks at most 0.44 (a track's running median); on validation renders no track's
        running median passes 0.83 (`valid60_people3b_high`; 0.39 on `valid60_people2`).
    facing_away_m, facing_window_s : a track that walked this far away from the camera (more
        than across the image) within the window faces away from it, and its published
        skeletons have their left and right joints exchanged, until it walks as far towards
        the camera (`core.people.facing`; 0: off, every person faces the camera).

    `confirm_frames`, `birth_score` and `trust_score`, and the foreground's second look, were
    chosen on validation renders (training subjects s01-s06, seed 201: `valid60_people2`, two
    people, 720 frames, and its twins with each person alone) by `tools/people_sweep.py`, for
    the shipped `rgbd_14`, by the mean MOTA of the three sets: second look, birth score 5, 2
    frames, trust score 7: 0.985 (two people: average7 86.6, IDF1 0.960, MOTA 0.953, 8 false
    skeletons per 1000 frames; alone: MOTA 1.000 and 1.000); trust score 9: 0.984; birth
    score 4 with 3 frames: 0.983; without the second look, the best 0.974; the settings before
    (no second look, the best region trusted at once) 0.943, a chair trusted in one alone
    video (83 false skeletons per 1000 frames).
    """

    max_people: int = 4
    confirm_frames: int = 2
    max_unseen_s: float = 1.0
    torso_std_m: float = 0.15
    max_speed_mps: float = 1.5
    gate_chi2: float = 16.0
    birth_score: float = 5.0
    max_gap_s: float = 0.5
    trust_score: float = 7.0
    hold_occluded: bool = True
    occluded_width_m: float = 0.09
    quiet_frames: int = 4
    max_held_s: float = math.inf
    max_hidden_s: float = 2.0
    detector_keep_s: float = 0.0
    confirmed_first: bool = True
    held_continues: bool = True
    held_own_front: bool = True
    held_needs_front: bool = True
    emerging_score: float = 3.0
    free_space_m: float = 1.5
    free_share: float = 0.9
    same_person_m: float = 0.3
    max_span_m: float = 2.7
    min_span_m: float = 0.5
    one_body_m: float = 0.6
    max_shoulders_m: float = 0.9
    facing_away_m: float = 0.45
    facing_window_s: float = 0.6
    tentative_margin: float = 9.0
    max_unseen_at_side_s: float = 0.07

    def __post_init__(self) -> None:
        if self.max_people < 1 or self.confirm_frames < 1 or self.quiet_frames < 0:
            raise ValueError(f'max_people and confirm_frames must be >= 1 and quiet_frames >= '
                             f'0, got {self.max_people}, {self.confirm_frames} and '
                             f'{self.quiet_frames}')
        for name in ('max_unseen_s', 'torso_std_m', 'max_speed_mps', 'gate_chi2', 'max_gap_s',
                     'occluded_width_m', 'max_held_s', 'max_hidden_s'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if not self.one_body_m >= 0:
            raise ValueError(f'one_body_m must be >= 0, got {self.one_body_m}')
        for name in ('max_shoulders_m', 'facing_away_m', 'facing_window_s',
                     'max_unseen_at_side_s'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        if not 0 <= self.min_span_m < self.max_span_m:
            raise ValueError(f'need 0 <= min_span_m < max_span_m, got {self.min_span_m} and '
                             f'{self.max_span_m}')
        if not self.detector_keep_s >= 0:
            raise ValueError(f'detector_keep_s must be >= 0, got {self.detector_keep_s}')
        if math.isnan(self.trust_score):
            raise ValueError('trust_score must be a number (inf: only the best region), got nan')
        if not self.same_person_m >= 0:
            raise ValueError(f'same_person_m must be >= 0, got {self.same_person_m}')
        if not (self.free_space_m >= 0 and 0 < self.free_share <= 1):
            raise ValueError(f'need free_space_m >= 0 and 0 < free_share <= 1, got '
                             f'{self.free_space_m} and {self.free_share}')
        if math.isnan(self.emerging_score):
            raise ValueError('emerging_score must be a number (inf: birth_score only), got nan')
