//! One hostile document per check, made by editing a small valid document; each error must be one
//! line naming the file and the element.

use std::io::Write;

use crate::{parse, parse_with, read_file, CommonRoad, Limits, ReadError, MAX_BOUND_POINTS, MAX_FILE_BYTES};

/// A small valid 2020a scenario: two lanelets, a traffic sign, a parked car, a car with a
/// three-state trajectory and a planning problem. Replaced fragments are unique in the text.
const MINI: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<commonRoad commonRoadVersion="2020a" benchmarkID="ZAM_Mini-1_1_T-1" date="2024-01-01" author="a" affiliation="b" source="c" timeStepSize="0.1">
  <location><geoNameId>-999</geoNameId><gpsLatitude>999</gpsLatitude><gpsLongitude>999</gpsLongitude></location>
  <scenarioTags><urban/></scenarioTags>
  <lanelet id="1">
    <leftBound><point><x>0.0</x><y>3.5</y></point><point><x>50.0</x><y>3.5</y></point></leftBound>
    <rightBound><point><x>0.0</x><y>0.0</y></point><point><x>50.0</x><y>0.0</y></point></rightBound>
    <successor ref="2"/>
    <laneletType>urban</laneletType>
    <trafficSignRef ref="5"/>
  </lanelet>
  <lanelet id="2">
    <leftBound><point><x>50.5</x><y>3.5</y></point><point><x>100.0</x><y>3.5</y></point></leftBound>
    <rightBound><point><x>50.5</x><y>0.0</y></point><point><x>100.0</x><y>0.0</y></point></rightBound>
    <predecessor ref="1"/>
    <adjacentLeft ref="1" drivingDir="same"/>
    <laneletType>urban</laneletType>
  </lanelet>
  <trafficSign id="5"><trafficSignElement><trafficSignID>274</trafficSignID><additionalValue>13.9</additionalValue></trafficSignElement></trafficSign>
  <staticObstacle id="20">
    <type>parkedVehicle</type>
    <shape><rectangle><length>4.4</length><width>1.7</width></rectangle></shape>
    <initialState><position><point><x>80.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time></initialState>
  </staticObstacle>
  <dynamicObstacle id="10">
    <type>car</type>
    <shape><rectangle><length>4.5</length><width>1.8</width></rectangle></shape>
    <initialState><position><point><x>10.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time><velocity><exact>10.0</exact></velocity></initialState>
    <trajectory>
      <state><position><point><x>11.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>1</exact></time><velocity><exact>10.1</exact></velocity></state>
      <state><position><point><x>12.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>2</exact></time><velocity><exact>10.2</exact></velocity></state>
      <state><position><point><x>13.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>3</exact></time><velocity><exact>10.3</exact></velocity></state>
    </trajectory>
  </dynamicObstacle>
  <planningProblem id="100">
    <initialState><position><point><x>0.5</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time><velocity><exact>8.0</exact></velocity><yawRate><exact>0.0</exact></yawRate><slipAngle><exact>0.0</exact></slipAngle></initialState>
    <goalState>
      <position><lanelet ref="2"/></position>
      <time><intervalStart>10</intervalStart><intervalEnd>50</intervalEnd></time>
    </goalState>
  </planningProblem>
</commonRoad>
"#;

/// A small valid 2018b scenario: one lanelet with a speed limit, an obstacle starting at step 5
/// with a rectangle position and interval values.
const MINI_2018B: &str = r#"<commonRoad commonRoadVersion="2018b" benchmarkID="ZAM_Old-1_1_T-1" timeStepSize="0.2" tags="urban critical">
  <lanelet id="1">
    <leftBound><point><x>0</x><y>3.5</y></point><point><x>50</x><y>3.5</y></point></leftBound>
    <rightBound><point><x>0</x><y>0</y></point><point><x>50</x><y>0</y></point></rightBound>
    <speedLimit>13.9</speedLimit>
  </lanelet>
  <obstacle id="7">
    <role>dynamic</role>
    <type>car</type>
    <shape><rectangle><length>4.5</length><width>1.8</width></rectangle></shape>
    <initialState>
      <position><rectangle><length>0.5</length><width>0.3</width><center><x>10</x><y>2</y></center></rectangle></position>
      <orientation><intervalStart>0.1</intervalStart><intervalEnd>0.3</intervalEnd></orientation>
      <time><exact>5</exact></time>
    </initialState>
    <trajectory>
      <state><position><point><x>12</x><y>2</y></point></position><orientation><exact>0</exact></orientation><time><exact>6</exact></time></state>
    </trajectory>
  </obstacle>
  <planningProblem id="1">
    <initialState><position><point><x>0</x><y>1</y></point></position><orientation><exact>0</exact></orientation><time><exact>0</exact></time><velocity><exact>5</exact></velocity></initialState>
    <goalState><time><intervalStart>0</intervalStart><intervalEnd>30</intervalEnd></time></goalState>
  </planningProblem>
</commonRoad>
"#;

/// `MINI` with `from` replaced by `to` (exactly one occurrence must exist).
fn edit(from: &str, to: &str) -> String {
    assert_eq!(MINI.matches(from).count(), 1, "fragment {from:?} must be unique");
    MINI.replacen(from, to, 1)
}

/// Parses `text` expecting an error; checks the line shape and returns it.
fn error_line(text: &str) -> String {
    error_with(text, &Limits::default())
}

/// [`error_line`] with other limits.
fn error_with(text: &str, limits: &Limits) -> String {
    let line = match parse_with(text, "hostile.xml", limits) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    };
    assert!(!line.contains('\n') && !line.contains('\r'), "one line: {line:?}");
    assert!(line.starts_with("hostile.xml: "), "{line}");
    line
}

/// Asserts that the error for `text` names `path` and mentions `message`.
fn rejects(text: &str, path: &str, message: &str) {
    let line = error_line(text);
    assert!(
        line.starts_with(&format!("hostile.xml: {path}: ")),
        "path {path:?} in {line}"
    );
    assert!(line.contains(message), "{message:?} in {line}");
}

/// Parses `text`, which must be valid.
fn accepts(text: &str) -> CommonRoad {
    parse(text, "ok.xml").unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn the_small_documents_are_valid() {
    let cr = accepts(MINI);
    assert_eq!((cr.lanelets.len(), cr.obstacles.len(), cr.duration_steps()), (2, 2, 3));
    assert_eq!(
        cr.ignored_line().as_deref(),
        Some("ignored: 1 location, 1 traffic sign, 1 traffic sign ref")
    );
    assert_eq!(cr.lanelet(2).and_then(|l| l.adjacent_left).map(|a| a.id), Some(1));
    let old = accepts(MINI_2018B);
    assert_eq!(old.tags, ["urban", "critical"]);
    assert_eq!(old.lanelets[0].speed_limit, Some(13.9));
    let states = &old.obstacles[0].states;
    assert_eq!(
        (states[0].time_step, states[0].position, states[1].time_step),
        (5, [10.0, 2.0], 6)
    );
    assert!((states[0].orientation - 0.2).abs() < 1e-12);
    assert_eq!((old.uncertain_states, old.duration_steps()), (1, 6));
}

#[test]
fn malformed_xml_names_line_and_column() {
    let line = error_line(&MINI[..MINI.len() / 2]);
    assert!(line.starts_with("hostile.xml: malformed XML: "), "{line}");
    let position = |word: &str| {
        word.split_once(':')
            .is_some_and(|(l, c)| l.parse::<u32>().is_ok() && c.parse::<u32>().is_ok())
    };
    assert!(line.split(' ').any(position), "line:column in {line}");
    let line = error_line(&edit(
        "</lanelet>\n  <lanelet id=\"2\">",
        "</lanelet>\n  <lanelet id=\"2\"></lanelet>",
    ));
    assert!(line.contains("at 18:"), "{line}");
    let dtd = MINI.replacen("<commonRoad ", "<!DOCTYPE x [<!ENTITY e \"x\">]>\n<commonRoad ", 1);
    assert!(error_line(&dtd).starts_with("hostile.xml: malformed XML: "));
}

#[test]
fn root_and_version_are_checked() {
    let text = MINI
        .replacen("<commonRoad ", "<scenario ", 1)
        .replacen("</commonRoad>", "</scenario>", 1);
    rejects(
        &text,
        "scenario",
        "expected root element <commonRoad>, found <scenario>",
    );
    rejects(
        &edit("\"2020a\"", "\"2019x\""),
        "commonRoad",
        "expected commonRoadVersion 2018b or 2020a, found \"2019x\"",
    );
    rejects(
        &edit("commonRoadVersion=\"2020a\" ", ""),
        "commonRoad",
        "expected a commonRoadVersion attribute",
    );
    rejects(&edit("\"2020a\"", "\"20&#10;20a\""), "commonRoad", "found \"20\\n20a\"");
}

#[test]
fn time_step_size_is_checked() {
    rejects(
        &edit(" timeStepSize=\"0.1\"", ""),
        "commonRoad",
        "expected a timeStepSize attribute",
    );
    for bad in ["NaN", "inf", "0", "-0.1", "10.5", "fast"] {
        let text = edit("timeStepSize=\"0.1\"", &format!("timeStepSize=\"{bad}\""));
        rejects(
            &text,
            "commonRoad",
            &format!("expected timeStepSize in (0, 10] seconds, found \"{bad}\""),
        );
    }
    assert_eq!(
        accepts(&edit("timeStepSize=\"0.1\"", "timeStepSize=\"10\"")).time_step,
        10.0
    );
}

#[test]
fn ids_must_be_unique() {
    rejects(
        &edit("<dynamicObstacle id=\"10\">", "<dynamicObstacle id=\"20\">"),
        "dynamicObstacle 20",
        "already used by staticObstacle 20 at line 20",
    );
    rejects(
        &edit("<trafficSign id=\"5\">", "<trafficSign id=\"2\">"),
        "trafficSign 2",
        "found id 2 already used by lanelet 2",
    );
    rejects(
        &edit("<lanelet id=\"2\">", "<lanelet id=\"1\">"),
        "lanelet 1",
        "expected a unique id, found id 1",
    );
    let problem = &MINI[MINI.find("<planningProblem").unwrap_or(0)..MINI.find("</commonRoad>").unwrap_or(0)];
    let second = MINI.replacen("</commonRoad>", &format!("{problem}</commonRoad>"), 1);
    rejects(&second, "planningProblem 100", "already used by planningProblem 100");
    rejects(
        &edit("<lanelet id=\"2\">", "<lanelet id=\"two\">"),
        "lanelet two",
        "expected id to be a non-negative integer, found \"two\"",
    );
    // Planning problems have their own id namespace (real OpenSCENARIO conversions reuse the ego's id).
    accepts(&edit("<planningProblem id=\"100\">", "<planningProblem id=\"10\">"));
}

#[test]
fn references_must_resolve_to_the_right_kind() {
    rejects(
        &edit("<successor ref=\"2\"/>", "<successor ref=\"99\"/>"),
        "lanelet 1 / successor",
        "expected ref to name an existing lanelet, found ref 99 (no such id)",
    );
    rejects(
        &edit("<successor ref=\"2\"/>", "<successor ref=\"20\"/>"),
        "lanelet 1 / successor",
        "found ref 20 naming staticObstacle 20",
    );
    rejects(
        &edit("<lanelet ref=\"2\"/>", "<lanelet ref=\"77\"/>"),
        "planningProblem 100 / goalState / position / lanelet",
        "found ref 77",
    );
    rejects(
        &edit(
            "<adjacentLeft ref=\"1\" drivingDir=\"same\"/>",
            "<adjacentLeft ref=\"3\" drivingDir=\"same\"/>",
        ),
        "lanelet 2 / adjacentLeft",
        "ref 3",
    );
    rejects(
        &edit("drivingDir=\"same\"", "drivingDir=\"sideways\""),
        "lanelet 2 / adjacentLeft",
        "expected drivingDir same or opposite, found \"sideways\"",
    );
    rejects(
        &edit("<successor ref=\"2\"/>", "<successor/>"),
        "lanelet 1 / successor",
        "expected an integer attribute ref, found none",
    );
    // A reference mjsafe does not follow (in an element it does not use) that names nothing, or
    // something of another kind, is counted, and the file read (commonroad-io reads it).
    let unresolved = |text: &str| {
        let cr = parse_with(text, "refs.xml", &Limits::default()).expect("reads");
        let line = cr.ignored_line().unwrap_or_default();
        (cr.ignored_count("ref/unresolved"), line)
    };
    let sign = edit(
        "<trafficSignID>274</trafficSignID>",
        "<trafficSignID>274</trafficSignID><foo ref=\"404\"/>",
    );
    let (count, line) = unresolved(&sign);
    assert_eq!(count, 1, "{line}");
    assert!(
        line.contains("1 reference to no element of its kind (in an element not used)"),
        "{line}"
    );
    let wrong_kind = edit("<trafficSignRef ref=\"5\"/>", "<trafficSignRef ref=\"2\"/>");
    assert_eq!(unresolved(&wrong_kind).0, 1);
    assert_eq!(unresolved(MINI).0, 0);
}

#[test]
fn a_lanelet_may_not_follow_itself_but_cycles_are_fine() {
    rejects(
        &edit("<predecessor ref=\"1\"/>", "<predecessor ref=\"2\"/>"),
        "lanelet 2 / predecessor",
        "found lanelet 2 as its own predecessor",
    );
    rejects(
        &edit("<successor ref=\"2\"/>", "<successor ref=\"1\"/>"),
        "lanelet 1 / successor",
        "found lanelet 1 as its own successor",
    );
    rejects(
        &edit("<adjacentLeft ref=\"1\"", "<adjacentLeft ref=\"2\""),
        "lanelet 2 / adjacentLeft",
        "found lanelet 2 as its own adjacentLeft",
    );
    let ring = edit(
        "<predecessor ref=\"1\"/>",
        "<predecessor ref=\"1\"/><successor ref=\"1\"/>",
    );
    let ring = ring.replacen(
        "<successor ref=\"2\"/>",
        "<predecessor ref=\"2\"/><successor ref=\"2\"/>",
        1,
    );
    assert_eq!(accepts(&ring).lanelet(2).map(|l| l.successors.clone()), Some(vec![1]));
}

#[test]
fn bounds_need_two_to_max_points() {
    let one = edit(
        "<point><x>0.0</x><y>3.5</y></point><point><x>50.0</x><y>3.5</y></point>",
        "<point><x>0.0</x><y>3.5</y></point>",
    );
    rejects(&one, "lanelet 1 / leftBound", "expected at least 2 <point>s, found 1");
    let many = "<point><x>1</x><y>2</y></point>".repeat(MAX_BOUND_POINTS + 1);
    let long = edit(
        "<point><x>0.0</x><y>3.5</y></point><point><x>50.0</x><y>3.5</y></point>",
        &many,
    );
    rejects(
        &long,
        "lanelet 1 / leftBound / point 10001",
        "expected at most 10000 points in a bound or polygon, found more",
    );
    let fine = edit(
        "<point><x>0.0</x><y>3.5</y></point><point><x>50.0</x><y>3.5</y></point>",
        &many[31..],
    );
    assert_eq!(accepts(&fine).lanelets[0].left.points.len(), MAX_BOUND_POINTS);
}

#[test]
fn count_limits_name_the_element_over_the_limit() {
    let limits = |f: fn(&mut Limits)| {
        let mut l = Limits::default();
        f(&mut l);
        l
    };
    let line = error_with(MINI, &limits(|l| l.max_total_points = 5));
    assert!(
        line.starts_with("hostile.xml: lanelet 2 / leftBound / point 2: expected at most 5 points in the file"),
        "{line}"
    );
    let line = error_with(MINI, &limits(|l| l.max_lanelets = 1));
    assert!(
        line.starts_with("hostile.xml: lanelet 2: expected at most 1 lanelets, found more"),
        "{line}"
    );
    let line = error_with(MINI, &limits(|l| l.max_obstacles = 1));
    assert!(
        line.starts_with("hostile.xml: dynamicObstacle 10: expected at most 1 obstacles"),
        "{line}"
    );
    let line = error_with(MINI, &limits(|l| l.max_states = 3));
    assert!(
        line.starts_with(
            "hostile.xml: dynamicObstacle 10 / trajectory / state 3: expected at most 3 states per obstacle"
        ),
        "{line}"
    );
    let line = error_with(MINI, &limits(|l| l.max_xml_nodes = 50));
    assert!(
        line.starts_with("hostile.xml: malformed XML: expected at most 50 XML nodes"),
        "{line}"
    );
    let line = error_with(MINI, &limits(|l| l.max_file_bytes = 100));
    assert!(
        line.starts_with("hostile.xml: expected at most 100 bytes, found"),
        "{line}"
    );
    assert_eq!(Limits::default().max_total_points, crate::MAX_TOTAL_POINTS);
}

#[test]
fn deep_nesting_is_refused_before_parsing() {
    let deep = format!("{}{}", "<a>".repeat(100), "</a>".repeat(100));
    let text = edit("<geoNameId>-999</geoNameId>", &deep);
    let line = error_line(&text);
    assert!(
        line.starts_with(
            "hostile.xml: malformed XML: expected elements nested at most 64 deep, found deeper at line 3"
        ),
        "{line}"
    );
    // A `/>` inside a quoted attribute value does not end the tag.
    let quoted = format!("{}{}", "<a b=\"x/>y\">".repeat(100), "</a>".repeat(100));
    assert!(error_line(&edit("<geoNameId>-999</geoNameId>", &quoted)).contains("nested at most 64 deep"));
    // Markup-like text in comments and CDATA does not count.
    let quiet = format!("<!-- {0} --><![CDATA[{0}]]><a b=\">\"/>", "<a>".repeat(100));
    accepts(&edit("<geoNameId>-999</geoNameId>", &quiet));
}

#[test]
fn values_must_be_finite_and_bounded() {
    let path = "dynamicObstacle 10 / trajectory / state 1 / position / point / x";
    rejects(
        &edit("<x>11.0</x>", "<x>1e300</x>"),
        path,
        "expected a finite number with |value| <= 1e7, found \"1e300\"",
    );
    rejects(&edit("<x>11.0</x>", "<x>NaN</x>"), path, "found \"NaN\"");
    rejects(&edit("<x>11.0</x>", "<x>-inf</x>"), path, "found \"-inf\"");
    rejects(&edit("<x>11.0</x>", "<x></x>"), path, "found \"\"");
    rejects(
        &edit("<exact>10.2</exact>", "<exact>2e7</exact>"),
        "dynamicObstacle 10 / trajectory / state 2 / velocity / exact",
        "found \"2e7\"",
    );
    rejects(
        &edit("<x>50.0</x><y>0.0</y>", "<x>50.0</x><y>1e8</y>"),
        "lanelet 1 / rightBound / point 2 / y",
        "|value| <= 1e7",
    );
    rejects(
        &edit("<x>11.0</x>", "<x>11.0</x><x>12</x>"),
        "dynamicObstacle 10 / trajectory / state 1 / position / point / x 2",
        "expected one <x>, found another",
    );
    assert_eq!(
        accepts(&edit("<x>11.0</x>", "<x>1e7</x>")).obstacles[1].states[1].position[0],
        1e7
    );
}

#[test]
fn shapes_need_positive_sizes_and_three_polygon_points() {
    rejects(
        &edit("<length>4.4</length>", "<length>0</length>"),
        "staticObstacle 20 / shape / rectangle / length",
        "expected a number > 0, found 0",
    );
    rejects(
        &edit("<width>1.7</width>", "<width>-1.7</width>"),
        "staticObstacle 20 / shape / rectangle / width",
        "expected a number > 0, found -1.7",
    );
    let circle = "<circle><radius>-1</radius></circle>";
    rejects(
        &edit("<rectangle><length>4.4</length><width>1.7</width></rectangle>", circle),
        "staticObstacle 20 / shape / circle / radius",
        "expected a number > 0",
    );
    let polygon = "<polygon><point><x>0</x><y>0</y></point><point><x>1</x><y>0</y></point></polygon>";
    rejects(
        &edit("<rectangle><length>4.4</length><width>1.7</width></rectangle>", polygon),
        "staticObstacle 20 / shape / polygon",
        "expected at least 3 <point>s, found 2",
    );
    rejects(
        &edit("<rectangle><length>4.4</length><width>1.7</width></rectangle>", ""),
        "staticObstacle 20 / shape",
        "expected at least one <rectangle>, <circle> or <polygon>",
    );
    let triangle = "<polygon><point><x>0</x><y>0</y></point><point><x>3</x><y>0</y></point>\
                    <point><x>0</x><y>3</y></point></polygon>";
    let cr = accepts(&edit(
        "<rectangle><length>4.4</length><width>1.7</width></rectangle>",
        triangle,
    ));
    assert_eq!(cr.obstacle(20).map(|o| o.shapes[0].center()), Some([1.0, 1.0]));
}

#[test]
fn trajectories_must_be_non_empty_and_consecutive() {
    let start = MINI.find("<trajectory>").unwrap_or(0);
    let end = MINI.find("</trajectory>").unwrap_or(0);
    let empty = format!(
        "{}<trajectory></trajectory>{}",
        &MINI[..start],
        &MINI[end + "</trajectory>".len()..]
    );
    rejects(
        &empty,
        "dynamicObstacle 10 / trajectory",
        "expected at least one <state> after the initial state in the trajectory, found none",
    );
    let none = format!("{}{}", &MINI[..start], &MINI[end + "</trajectory>".len()..]);
    rejects(
        &none,
        "dynamicObstacle 10",
        "expected a <trajectory> or an <occupancySet>, found neither",
    );
    let state2 = "dynamicObstacle 10 / trajectory / state 2 / time";
    rejects(
        &edit("<exact>2</exact>", "<exact>1</exact>"),
        state2,
        "expected time step 2, found 1 (not after 1)",
    );
    rejects(
        &edit("<exact>2</exact>", "<exact>5</exact>"),
        state2,
        "expected time step 2, found 5 (a gap after 1)",
    );
    rejects(
        &edit("<exact>2</exact>", "<exact>2.5</exact>"),
        "dynamicObstacle 10 / trajectory / state 2 / time / exact",
        "expected an integer time step",
    );
    let interval = "<intervalStart>2</intervalStart><intervalEnd>3</intervalEnd>";
    rejects(
        &edit("<exact>2</exact>", interval),
        state2,
        "expected an <exact> time step, found the interval 2..3",
    );
}

/// Asserts that one of the file's notes starts with `start`.
fn assert_noted(cr: &CommonRoad, start: &str) {
    let notes = cr.notes();
    assert!(notes.iter().any(|n| n.starts_with(start)), "{start:?} in {notes:?}");
}

/// The time steps of road user `id`'s states.
fn steps_of(cr: &CommonRoad, id: u64) -> Vec<i64> {
    let states = &cr.obstacle(id).expect("the road user").states;
    states.iter().map(|s| s.time_step).collect()
}

/// Road user 10's first trajectory state, and its initial state's time and velocity.
const FIRST_STATE: &str = "<state><position><point><x>11.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>1</exact></time><velocity><exact>10.1</exact></velocity></state>";
const INITIAL_TIME: &str = "<time><exact>0</exact></time><velocity><exact>10.0</exact>";

/// What files converted from datasets or written by CommonRoad's tools have and commonroad-io
/// reads: a 2020a road user or static obstacle starting after step 0, a trajectory whose first
/// state repeats the initial state, an isLeftOf naming a lanelet or nothing. Each is read and named
/// in one remark; a repeated state that differs and a planning problem starting late stay errors.
#[test]
fn what_dataset_files_do_is_read_and_named() {
    let parsed = |text: &str| parse_with(text, "converted.xml", &Limits::default()).expect("reads");
    // Road user 10 appears at step 1: its initial state at step 1, its trajectory from step 2.
    let late = edit(FIRST_STATE, "").replacen(
        INITIAL_TIME,
        "<time><exact>1</exact></time><velocity><exact>10.0</exact>",
        1,
    );
    let cr = parsed(&late);
    let steps = steps_of(&cr, 10);
    assert_eq!((cr.late_starts, steps), (1, vec![1, 2, 3]));
    assert_noted(&cr, "1 road user starts after time step 0");
    // The trajectory repeats the initial state at step 0: read once.
    let initial = "<state><position><point><x>10.0</x><y>1.75</y></point></position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time><velocity><exact>10.0</exact></velocity></state>";
    let repeated = edit(FIRST_STATE, &format!("{initial}{FIRST_STATE}"));
    let cr = parsed(&repeated);
    let steps = steps_of(&cr, 10);
    assert_eq!((cr.repeated_initial_states, steps), (1, vec![0, 1, 2, 3]));
    assert_eq!(cr.obstacle(10), parsed(MINI).obstacle(10));
    assert_noted(&cr, "1 trajectory repeats");
    let differing = edit(
        FIRST_STATE,
        &format!(
            "{}{FIRST_STATE}",
            initial.replace("10.0</exact></velocity>", "10.5</exact></velocity>")
        ),
    );
    rejects(
        &differing,
        "dynamicObstacle 10 / trajectory / state 1 / time",
        "expected time step 1, found 0 (not after 0)",
    );
    // An isLeftOf naming a lanelet, in an intersection (ignored as a whole).
    let intersection = |left_of: &str| {
        edit(
            "  <staticObstacle id=\"20\">",
            &format!("  <intersection id=\"30\"><incoming id=\"31\"><incomingLanelet ref=\"1\"/><isLeftOf ref=\"{left_of}\"/></incoming></intersection>\n  <staticObstacle id=\"20\">"),
        )
    };
    let cr = parsed(&intersection("2"));
    assert_eq!(
        (cr.ignored_count("intersection"), cr.ignored_count("ref/unresolved")),
        (1, 1)
    );
    assert_eq!(parsed(&intersection("31")).ignored_count("ref/unresolved"), 0);
    // One naming nothing, as a stop line's sign some files leave out: counted too.
    assert_eq!(parsed(&intersection("99")).ignored_count("ref/unresolved"), 1);
    // A static obstacle starting after step 0: static at every step, as commonroad-io reads it.
    let late_static = edit(
        "<orientation><exact>0.0</exact></orientation><time><exact>0</exact></time></initialState>",
        "<orientation><exact>0.0</exact></orientation><time><exact>1</exact></time></initialState>",
    );
    let cr = parsed(&late_static);
    assert_eq!((cr.late_static, cr.late_starts), (1, 0));
    assert_noted(&cr, "1 static obstacle starts after time step 0");
}

#[test]
fn the_2018b_rules() {
    let role = MINI_2018B.replacen("<role>dynamic</role>", "<role>flying</role>", 1);
    rejects(
        &role,
        "obstacle 7 / role",
        "expected role static or dynamic, found \"flying\"",
    );
    let no_role = MINI_2018B.replacen("<role>dynamic</role>", "", 1);
    rejects(&no_role, "obstacle 7", "expected a <role>, found none");
    let gap = MINI_2018B.replacen("<exact>6</exact>", "<exact>8</exact>", 1);
    rejects(
        &gap,
        "obstacle 7 / trajectory / state / time",
        "expected time step 6, found 8 (a gap after 5)",
    );
    let lanelet_position = MINI_2018B.replacen("<point><x>12</x><y>2</y></point>", "<lanelet ref=\"1\"/>", 1);
    rejects(
        &lanelet_position,
        "obstacle 7 / trajectory / state / position / lanelet",
        "found a lanelet reference (allowed in goals only)",
    );
}

#[test]
fn planning_problems_need_ordered_goals() {
    let goal = "<goalState>\n      <position><lanelet ref=\"2\"/></position>\n      \
                <time><intervalStart>10</intervalStart><intervalEnd>50</intervalEnd></time>\n    </goalState>";
    rejects(
        &edit(goal, ""),
        "planningProblem 100",
        "expected at least one <goalState>, found none",
    );
    let reversed = "<intervalStart>50</intervalStart><intervalEnd>10</intervalEnd>";
    rejects(
        &edit(
            "<intervalStart>10</intervalStart><intervalEnd>50</intervalEnd>",
            reversed,
        ),
        "planningProblem 100 / goalState / time",
        "expected intervalStart <= intervalEnd, found 50 > 10",
    );
    rejects(
        &edit("<intervalEnd>50</intervalEnd>", ""),
        "planningProblem 100 / goalState / time",
        "expected <exact> or <intervalStart> and <intervalEnd>, found <intervalStart>",
    );
    rejects(
        &edit("<lanelet ref=\"2\"/>", "<point><x>1</x><y>1</y></point>"),
        "planningProblem 100 / goalState / position / point",
        "found a <point>",
    );
    let initial = "<time><exact>0</exact></time><velocity><exact>8.0</exact>";
    rejects(
        &edit(initial, "<time><exact>3</exact></time><velocity><exact>8.0</exact>"),
        "planningProblem 100 / initialState / time",
        "expected initial time step 0",
    );
    rejects(
        &edit(
            "<orientation><exact>0.0</exact></orientation><time><exact>0</exact></time><velocity><exact>8.0</exact>",
            "<time><exact>0</exact></time><velocity><exact>8.0</exact>",
        ),
        "planningProblem 100 / initialState",
        "expected a <orientation>, found none",
    );
}

#[test]
fn unknown_elements_and_z_are_counted_not_dropped() {
    let text = edit(
        "<laneletType>urban</laneletType>\n    <trafficSignRef",
        "<laneletType>urban</laneletType><bar/>\n    <trafficSignRef",
    )
    .replacen("<x>0.5</x><y>1.75</y>", "<x>0.5</x><y>1.75</y><z>3</z>", 1)
    .replacen("</commonRoad>", "<foo/><foo/><steeringAngle/></commonRoad>", 1);
    let cr = accepts(&text);
    assert_eq!(
        (cr.ignored_count("foo"), cr.ignored_count("bar"), cr.ignored_count("z")),
        (2, 1, 1)
    );
    let line = cr.ignored_line().unwrap_or_default();
    assert!(
        line.contains("2 unknown <foo>") && line.contains("1 z coordinate") && line.contains("1 steering angle"),
        "{line}"
    );
}

#[test]
fn read_file_refuses_big_special_and_missing_files() {
    let dir = std::env::temp_dir().join(format!("mjsafe-commonroad-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let line = read_file(&dir).map(|_| ()).expect_err("a directory").to_string();
    assert!(line.ends_with(": expected a regular file, found a directory"), "{line}");
    let big = dir.join("big.xml");
    std::fs::File::create(&big)
        .and_then(|f| f.set_len(MAX_FILE_BYTES + 1))
        .expect("sparse file");
    let err = read_file(&big).map(|_| ()).expect_err("too large");
    assert!(
        matches!(err, ReadError::TooLarge { size, .. } if size == MAX_FILE_BYTES + 1),
        "{err}"
    );
    let latin = dir.join("latin.xml");
    std::fs::File::create(&latin)
        .and_then(|mut f| f.write_all(b"<commonRoad author=\"\xe9\"/>"))
        .expect("file");
    let line = read_file(&latin).map(|_| ()).expect_err("not UTF-8").to_string();
    assert!(line.contains("latin.xml: cannot read: not UTF-8 text"), "{line}");
    let missing = read_file(&dir.join("missing.xml")).map(|_| ()).expect_err("missing");
    assert!(matches!(missing, ReadError::Io { .. }), "{missing}");
    if cfg!(unix) {
        let null = read_file(std::path::Path::new("/dev/null"))
            .map(|_| ())
            .expect_err("a device");
        assert!(matches!(null, ReadError::NotRegularFile { .. }), "{null}");
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn no_panic_on_truncations_or_byte_edits() {
    for cut in 0..MINI.len() {
        let _ = parse(&MINI[..cut], "cut.xml");
    }
    for (i, byte) in MINI.bytes().enumerate() {
        for replacement in ["", "9", "<", "e400"] {
            if byte.is_ascii_alphanumeric() || b"<>/\"=.-".contains(&byte) {
                let text = format!("{}{replacement}{}", &MINI[..i], &MINI[i + 1..]);
                if let Err(e) = parse(&text, "edit.xml") {
                    assert!(!e.to_string().contains('\n'), "{e}");
                }
            }
        }
    }
}

/// Goal states that differ only in their regions make an exact union; ones that differ in their
/// windows or intervals (or in having a position) must be asked one by one.
#[test]
fn goal_states_that_differ_in_more_than_their_regions_are_told_apart() {
    let goal = "<goalState>\n      <position><lanelet ref=\"2\"/></position>\n      \
                <time><intervalStart>10</intervalStart><intervalEnd>50</intervalEnd></time>\n    </goalState>";
    let differ = |text: &str| -> bool {
        let cr = parse(text, "goals.xml").unwrap_or_else(|e| panic!("{e}"));
        cr.planning_problems[0].goal_states_differ()
    };
    assert!(!differ(MINI));
    let regions = goal.to_string() + "\n    " + &goal.replace("ref=\"2\"", "ref=\"1\"");
    assert!(!differ(&edit(goal, &regions)));
    let windows = goal.to_string() + "\n    " + &goal.replace("<intervalEnd>50", "<intervalEnd>60");
    assert!(differ(&edit(goal, &windows)));
    let anywhere = goal.to_string()
        + "\n    "
        + "<goalState><time><intervalStart>10</intervalStart><intervalEnd>50</intervalEnd></time></goalState>";
    assert!(differ(&edit(goal, &anywhere)));
}

/// A road user's `<originXShift>` s (commonroad-io 2026's `RectObstacleShape`) puts the
/// rectangle's centre s behind its states' positions along the length axis; |s| above half the
/// length is one line naming it; in a goal's rectangle, where commonroad-io reads none, it is
/// counted as ignored.
#[test]
fn an_origin_shift_moves_a_road_users_rectangle() {
    let car = "<shape><rectangle><length>4.5</length><width>1.8</width></rectangle></shape>";
    let shifted = |s: &str| {
        car.replace(
            "</width>",
            &format!("</width><orientation>0.5</orientation><originXShift>{s}</originXShift>"),
        )
    };
    let cr = accepts(&edit(car, &shifted("-1.2")));
    let centre = cr.obstacle(10).unwrap().shapes[0].center();
    let expected = [1.2 * 0.5f64.cos(), 1.2 * 0.5f64.sin()];
    assert!(
        (centre[0] - expected[0]).abs() < 1e-15 && (centre[1] - expected[1]).abs() < 1e-15,
        "{centre:?}"
    );
    assert_eq!(cr.ignored_count("originXShift"), 0);
    rejects(
        &edit(car, &shifted("2.3")),
        "dynamicObstacle 10 / shape / rectangle / originXShift",
        "expected |originXShift| <= length / 2 = 2.25, found 2.3",
    );
    let goal = "<position><lanelet ref=\"2\"/></position>";
    let rectangle = "<position><rectangle><length>4</length><width>3</width><center><x>60</x><y>1.75</y></center>\
                     <originXShift>1</originXShift></rectangle></position>";
    let cr = accepts(&edit(goal, rectangle));
    assert_eq!(cr.ignored_count("originXShift"), 1);
}
