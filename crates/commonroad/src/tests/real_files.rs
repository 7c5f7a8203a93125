//! The real scenarios: everything parses, counts match the XML text, values match spot checks.

use std::collections::BTreeMap;

use super::{count, number_after, reading_all, real, real_files, text_of};
use crate::{read_file, GoalPosition, ObstacleRole, ReadError, Shape, Version};

#[test]
fn every_real_file_parses_and_matches_text_counts() {
    let files = real_files();
    assert!(
        files.len() >= 13,
        "expected the 13+ real scenarios, found {}",
        files.len()
    );
    for path in files.iter().chain([&reading_all()]) {
        let text = text_of(path);
        let cr = read_file(path).unwrap_or_else(|e| panic!("{e}"));
        let name = path.display();
        assert_eq!(cr.lanelets.len(), count(&text, "<lanelet id="), "{name}: lanelets");
        assert_eq!(
            cr.planning_problems.len(),
            count(&text, "<planningProblem "),
            "{name}: planning problems"
        );
        let dynamic: Vec<_> = cr
            .obstacles
            .iter()
            .filter(|o| o.role == ObstacleRole::Dynamic)
            .collect();
        let occupancy_only = cr.ignored_count("dynamicObstacle/occupancySet");
        let expected = count(&text, "<dynamicObstacle ") + count(&text, "<role>dynamic</role>") - occupancy_only;
        assert_eq!(dynamic.len(), expected, "{name}: dynamic obstacles");
        let statics = cr.obstacles.len() - dynamic.len();
        let expected = count(&text, "<staticObstacle ") + count(&text, "<role>static</role>");
        assert_eq!(statics, expected, "{name}: static obstacles");
        let states: usize = dynamic.iter().map(|o| o.states.len()).sum();
        assert_eq!(
            states,
            count(&text, "<state>") + dynamic.len(),
            "{name}: dynamic states"
        );
        let version = if text.contains("commonRoadVersion=\"2018b\"") {
            Version::V2018b
        } else {
            Version::V2020a
        };
        assert_eq!(cr.version, version, "{name}");
        for o in &cr.obstacles {
            let steps: Vec<i64> = o.states.iter().map(|s| s.time_step).collect();
            assert!(
                steps.windows(2).all(|w| w[1] == w[0] + 1),
                "{name}: obstacle {} steps",
                o.id
            );
        }
        assert!(cr
            .ignored_line()
            .is_none_or(|line| line.starts_with("ignored: ") && !line.contains('\n')));
    }
}

/// A file, its time step and its road users by type.
type Catalogued = (&'static str, f64, &'static [(&'static str, usize)]);

#[test]
fn road_users_match_the_catalogue() {
    // From shared/notes/real-world.md (counted in the source repositories).
    let table: &[Catalogued] = &[
        ("USA_US101-4_1_T-1.xml", 0.1, &[("car", 22)]),
        ("USA_US101-3_3_T-1.xml", 0.1, &[("car", 12)]),
        ("USA_Lanker-1_1_T-1.xml", 0.1, &[("car", 24)]),
        ("USA_Peach-4_8_T-1.xml", 0.1, &[("car", 9)]),
        (
            "ARG_Carcarana-4_5_T-1.xml",
            0.1,
            &[("bus", 1), ("car", 5), ("truck", 2)],
        ),
        (
            "FRA_Anglet-1_1_T-1.xml",
            0.1,
            &[("car", 6), ("motorcycle", 1), ("truck", 1)],
        ),
        ("DEU_A9-3_1_T-1.xml", 0.2, &[("car", 9)]),
        (
            "OSC_PedestrianCollision-1_1_T-1.xml",
            0.1,
            &[("car", 1), ("pedestrian", 1)],
        ),
        (
            "DEU_Moelln-10_2_T-1.xml",
            0.1,
            &[("bicycle", 2), ("car", 7), ("truck", 1)],
        ),
        ("USA_US101-5_1_T-1.xml", 0.1, &[("car", 25)]),
    ];
    for (file, dt, kinds) in table {
        let cr = read_file(&real(file)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cr.time_step, *dt, "{file}");
        let mut found: BTreeMap<&str, usize> = BTreeMap::new();
        for o in &cr.obstacles {
            *found.entry(o.kind.as_str()).or_default() += 1;
        }
        let expected: BTreeMap<&str, usize> = kinds.iter().copied().collect();
        assert_eq!(found, expected, "{file}");
    }
    let lanelets = [
        ("USA_US101-4_1_T-1.xml", 12),
        ("USA_Lanker-1_1_T-1.xml", 91),
        ("ARG_Carcarana-4_5_T-1.xml", 368),
    ];
    for (file, n) in lanelets {
        assert_eq!(
            read_file(&real(file)).map(|cr| cr.lanelets.len()).ok(),
            Some(n),
            "{file}"
        );
    }
}

#[test]
fn first_bound_point_of_every_file_matches_the_text() {
    for path in real_files() {
        let text = text_of(&path);
        let cr = read_file(&path).unwrap_or_else(|e| panic!("{e}"));
        let anchor = "<lanelet id=";
        let first = cr.lanelets[0].left.points[0];
        assert_eq!(
            first,
            [number_after(&text, anchor, "x"), number_after(&text, anchor, "y")],
            "{}",
            path.display()
        );
    }
}

#[test]
fn us101_4_1_lanelet_obstacle_and_planning_problem() {
    let cr = read_file(&real("USA_US101-4_1_T-1.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        (cr.benchmark_id.as_str(), cr.version, cr.time_step),
        ("USA_US101-4_1_T-1", Version::V2020a, 0.1)
    );
    assert_eq!(cr.duration_steps(), 100);
    assert!(cr.tags.iter().any(|t| t == "highway"));
    let lanelet = cr.lanelet(2).expect("lanelet 2");
    assert_eq!(lanelet.left.points.len(), 25);
    assert_eq!(lanelet.left.points[0], [-40.54872163, 40.24680481]);
    assert_eq!(lanelet.right.points.last(), Some(&[24.2999, -24.2479]));

    let car = cr.obstacle(380).expect("obstacle 380");
    assert_eq!(
        (car.kind.as_str(), car.role, car.states.len()),
        ("car", ObstacleRole::Dynamic, 13)
    );
    assert_eq!(
        car.shapes,
        vec![Shape::Rectangle {
            length: 5.1816,
            width: 2.5908,
            orientation: 0.0,
            center: [0.0, 0.0]
        }]
    );
    let s = car.state_at(10).expect("state at step 10");
    assert_eq!(
        (s.time_step, s.position, s.orientation),
        (10, [33.3603, -39.9544], -0.7186)
    );
    assert_eq!(
        (s.velocity, s.acceleration, s.yaw_rate),
        (Some(11.0338), Some(-0.72847), None)
    );
    assert!(car.state_at(13).is_none() && car.state_at(-1).is_none());

    let pp = cr.planning_problem(None).expect("first planning problem");
    assert_eq!(pp.id, 458);
    assert_eq!(cr.planning_problem(Some(458)).map(|p| p.id).ok(), Some(458));
    let i = pp.initial;
    assert_eq!(
        (i.time_step, i.position, i.velocity, i.orientation),
        (0, [0.0, 0.0], Some(5.331), -0.76501)
    );
    assert_eq!((i.yaw_rate, i.slip_angle), (Some(-0.007396), Some(0.000997)));
    let goal = &pp.goals[0];
    assert_eq!(goal.time_steps, (90, 100));
    assert_eq!(
        (goal.orientation, goal.velocity),
        (Some((-0.81093, -0.63639)), Some((0.0, 3.0)))
    );
    let rectangle = Shape::Rectangle {
        length: 2.2678,
        width: 1.7444,
        orientation: -0.73431,
        center: [17.836, -17.2178],
    };
    assert_eq!(goal.position, Some(GoalPosition::Shapes(vec![rectangle])));
}

#[test]
fn unknown_planning_problem_lists_the_ids() {
    let cr = read_file(&real("USA_US101-4_1_T-1.xml")).unwrap_or_else(|e| panic!("{e}"));
    let err = cr.planning_problem(Some(7)).expect_err("no planning problem 7");
    let line = err.to_string();
    assert!(
        line.contains("USA_US101-4_1_T-1.xml: planningProblem: expected planning problem 7"),
        "{line}"
    );
    assert!(line.ends_with("found planning problem ids: 458"), "{line}");
    assert!(matches!(err, ReadError::Invalid { .. }));
}

#[test]
fn files_from_2018b_read() {
    let cr = read_file(&real("USA_US101-3_3_T-1.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cr.version, Version::V2018b);
    assert!(cr.tags.contains(&"lane_change".to_string()) && cr.tags.contains(&"critical".to_string()));
    let goal = &cr.planning_problem(Some(396)).expect("planning problem 396").goals[0];
    assert_eq!((goal.time_steps, goal.velocity), ((30, 31), Some((0.0, 8.6007))));
    assert_eq!(goal.position, Some(GoalPosition::Lanelets(vec![31])));
    assert_eq!(
        cr.lanelet(31)
            .and_then(|l| l.adjacent_right)
            .map(|a| (a.id, a.same_direction)),
        Some((33, true))
    );

    let text = text_of(&real("USA_Lanker-1_1_T-1.xml"));
    let cr = read_file(&real("USA_Lanker-1_1_T-1.xml")).unwrap_or_else(|e| panic!("{e}"));
    let limits = cr.lanelets.iter().filter(|l| l.speed_limit.is_some()).count();
    assert_eq!(limits, count(&text, "<speedLimit>"));
    assert_eq!(
        cr.lanelets[0].speed_limit,
        Some(number_after(&text, "<lanelet id=", "speedLimit"))
    );
    assert!(cr.ignored.is_empty(), "{:?}", cr.ignored);

    let text = text_of(&real("DEU_A9-3_1_T-1.xml"));
    let cr = read_file(&real("DEU_A9-3_1_T-1.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cr.time_step, 0.2);
    let o = cr.obstacle(3536).expect("obstacle 3536");
    let s = o.states[0];
    assert_eq!(s.position, [351.6643758281, -5866.331045464546]);
    assert!((s.orientation - (0.0011 + 0.0347) / 2.0).abs() < 1e-12);
    assert!((s.velocity.unwrap_or(f64::NAN) - (27.0104 + 27.4908) / 2.0).abs() < 1e-12);
    // Every obstacle state here has a rectangle position and interval values.
    let obstacle_states = count(&text, "<state>") + count(&text, "<obstacle ");
    assert_eq!(cr.uncertain_states, obstacle_states);
    assert!(cr
        .notes()
        .iter()
        .any(|n| n.starts_with(&format!("{obstacle_states} states with interval values"))));
}

#[test]
fn peach_ignored_line_names_its_traffic_lights() {
    let path = real("USA_Peach-4_8_T-1.xml");
    let text = text_of(&path);
    let cr = read_file(&path).unwrap_or_else(|e| panic!("{e}"));
    let lights = count(&text, "<trafficLight ");
    assert_eq!(lights, 4);
    let line = cr.ignored_line().expect("something ignored");
    assert!(line.contains(&format!("{lights} traffic lights")), "{line}");
    assert!(
        line.contains(&format!("{} traffic signs", count(&text, "<trafficSign "))),
        "{line}"
    );
    assert!(
        line.contains(&format!("{} stop lines", count(&text, "<stopLine>"))),
        "{line}"
    );
    assert_eq!(cr.ignored_count("trafficLight"), lights);
}

#[test]
fn reading_all_shapes_and_ignored_kinds() {
    let cr = read_file(&reading_all()).unwrap_or_else(|e| panic!("{e}"));
    let lanelet = cr.lanelet(100).expect("lanelet 100");
    assert_eq!(
        (lanelet.left.marking.as_deref(), lanelet.right.marking.as_deref()),
        (Some("dashed"), Some("solid"))
    );
    assert_eq!(lanelet.types, ["highway", "mainCarriageWay"]);
    assert_eq!(
        lanelet.adjacent_left.map(|a| (a.id, a.same_direction)),
        Some((103, true))
    );
    let parked = cr.obstacle(3).expect("static obstacle 3");
    assert_eq!((parked.role, parked.states.len()), (ObstacleRole::Static, 1));
    assert_eq!(
        parked.shapes,
        vec![Shape::Circle {
            radius: 2.0,
            center: [0.0, 0.0]
        }]
    );
    assert_eq!(parked.state_at(1000).map(|s| s.time_step), Some(0));
    assert!(cr.obstacle(1).is_none(), "obstacle 1 has an occupancy set only");
    assert_eq!(cr.obstacle(2).map(|o| o.states.len()), Some(2));
    let goals = &cr.planning_problem(Some(1000)).expect("planning problem 1000").goals;
    let rectangle = Shape::Rectangle {
        length: 4.3,
        width: 8.9,
        orientation: 1.7,
        center: [2.5, -1.8],
    };
    assert_eq!(goals[0].position, Some(GoalPosition::Shapes(vec![rectangle])));
    let circle = Shape::Circle {
        radius: 2.0,
        center: [10.0, 0.0],
    };
    assert_eq!(goals[1].position, Some(GoalPosition::Shapes(vec![circle])));
    for element in [
        "dynamicObstacle/occupancySet",
        "environmentObstacle",
        "phantomObstacle",
        "trafficSign",
        "location",
    ] {
        assert_eq!(cr.ignored_count(element), 1, "{element}");
    }
    let line = cr.ignored_line().expect("ignored");
    assert!(line.contains("1 dynamic obstacle with an occupancy set only"), "{line}");
    assert_eq!(cr.tags, ["intersection", "urban"]);
}

/// The largest real file (1.2 MB) parses whole (timings are measured by benchmarks, not tests).
#[test]
fn largest_real_file_parses() {
    let path = real("DEU_Flensburg-10_1_T-1.xml");
    let text = text_of(&path);
    assert!(text.len() > 1_200_000);
    let cr = crate::parse(&text, "DEU_Flensburg-10_1_T-1.xml").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cr.obstacles.len(), 27);
}
