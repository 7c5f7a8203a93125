//! A formula's text: tokens, the parser (precedence climbing over RTAMT's operator table) and
//! the canonical text ([`std::fmt::Display`] of [`Formula`]).
//!
//! RTAMT's grammar (ANTLR, `StlParser.g4`) lists its alternatives from the tightest to the
//! loosest: unary `-`; `*`; `+` `-`; comparisons; the prefix operators (`not`, `always`, …,
//! whose operand takes everything tighter than `until`); `until`; `since`; `and`; `or`;
//! `implies`; `iff`; `xor` — each binary one left-associative. The levels below are those.

use std::fmt::{self, Write};

use super::{Comparison, Connective, Formula, Interval, Node, Prefix, StlError, Term, MAX_DEPTH, MAX_TEXT};

/// Binding levels (higher binds tighter).
const XOR: u8 = 1;
const IFF: u8 = 2;
const IMPLIES: u8 = 3;
const OR: u8 = 4;
const AND: u8 = 5;
const SINCE: u8 = 6;
const UNTIL: u8 = 7;
/// The operand of a prefix operator (`not`, `always`, …) takes operators above this.
const PREFIX: u8 = 8;
const COMPARE: u8 = 9;
const ADD: u8 = 10;
const MULTIPLY: u8 = 11;
/// Unary minus; its operand is a primary.
const NEGATE: u8 = 12;
const PRIMARY: u8 = 13;

/// Words that are operators (a signal of such a name is quoted).
const KEYWORDS: &[&str] = &[
    "not",
    "and",
    "or",
    "implies",
    "iff",
    "xor",
    "always",
    "eventually",
    "until",
    "historically",
    "once",
    "since",
    "G",
    "F",
    "U",
    "H",
    "O",
    "S",
    "true",
    "false",
    "TRUE",
    "FALSE",
    "abs",
];

/// RTAMT's operators this module does not evaluate.
const UNSUPPORTED: &[&str] = &[
    "next", "prev", "X", "Y", "s_next", "s_prev", "sX", "sY", "rise", "fall", "unless", "W", "sqrt", "exp", "pow",
    "log", "ln",
];

/// Parses a formula (see the module documentation for the syntax). Errors name the 1-based
/// character column and what was expected there.
pub fn parse(text: &str) -> Result<Formula, StlError> {
    if text.len() > MAX_TEXT {
        return Err(StlError::Parse {
            column: 1,
            message: format!(
                "the formula is {} bytes long, more than the {MAX_TEXT} allowed",
                text.len()
            ),
        });
    }
    let tokens = lex(text)?;
    let mut p = Parser {
        tokens,
        pos: 0,
        signals: Vec::new(),
        nesting: 0,
    };
    let e = p.expr(0)?;
    let t = p.peek();
    if t.tok != Tok::End {
        return Err(p.error_at(t, "an operator or the end of the formula"));
    }
    match e.value {
        Value::Condition(root) => Ok(Formula {
            root,
            signals: p.signals,
        }),
        Value::Number(_) => Err(StlError::Parse {
            column: e.column,
            message: "the formula is a value, not a condition: compare it, e.g. `x > 0`".into(),
        }),
    }
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    /// A plain name: a signal, a keyword or a unit.
    Name(String),
    /// A quoted signal name.
    Quoted(String),
    Number(f64),
    LParen,
    RParen,
    LBracket,
    RBracket,
    Comma,
    Colon,
    Compare(Comparison),
    Bang,
    And,
    Or,
    Implies,
    Iff,
    Plus,
    Minus,
    Star,
    End,
}

#[derive(Debug, Clone)]
struct Token {
    tok: Tok,
    /// 1-based character column.
    column: usize,
    /// The source text (for messages).
    text: String,
}

fn name_start(c: char) -> bool {
    c.is_ascii_alphabetic() || c == '_' || c == '/'
}

fn name_part(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_' || c == '.' || c == '/'
}

fn lex(text: &str) -> Result<Vec<Token>, StlError> {
    let chars: Vec<char> = text.chars().collect();
    let at = |i: usize| chars.get(i).copied().unwrap_or('\0');
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        let err = |message: String| StlError::Parse {
            column: start + 1,
            message,
        };
        let tok = match c {
            '(' => Tok::LParen,
            ')' => Tok::RParen,
            '[' => Tok::LBracket,
            ']' => Tok::RBracket,
            ',' => Tok::Comma,
            ':' => Tok::Colon,
            '+' => Tok::Plus,
            '*' => Tok::Star,
            '<' if at(i + 1) == '-' && at(i + 2) == '>' => {
                i += 2;
                Tok::Iff
            }
            '<' | '>' => {
                let or_equal = at(i + 1) == '=';
                i += usize::from(or_equal);
                Tok::Compare(match (c, or_equal) {
                    ('<', false) => Comparison::Less,
                    ('<', true) => Comparison::LessEqual,
                    ('>', false) => Comparison::Greater,
                    _ => Comparison::GreaterEqual,
                })
            }
            '=' if at(i + 1) == '=' => {
                i += 1;
                Tok::Compare(Comparison::Equal)
            }
            '=' => return Err(err("expected `==` (a comparison), found `=`".into())),
            '!' if at(i + 1) == '=' => {
                // `!=`, or RTAMT's `!==`.
                i += if at(i + 2) == '=' { 2 } else { 1 };
                Tok::Compare(Comparison::NotEqual)
            }
            '!' => Tok::Bang,
            '&' => {
                i += usize::from(at(i + 1) == '&');
                Tok::And
            }
            '|' => {
                i += usize::from(at(i + 1) == '|');
                Tok::Or
            }
            '-' if at(i + 1) == '>' => {
                i += 1;
                Tok::Implies
            }
            '-' => Tok::Minus,
            '"' | '`' => {
                let Some(len) = chars[i + 1..].iter().position(|&q| q == c) else {
                    return Err(err(format!("a name opened with {c} is not closed")));
                };
                if len == 0 {
                    return Err(err("expected a signal name inside the quotes, found none".into()));
                }
                let name: String = chars[i + 1..i + 1 + len].iter().collect();
                i += len + 1;
                Tok::Quoted(name)
            }
            _ if c.is_ascii_digit() || (c == '.' && at(i + 1).is_ascii_digit()) => {
                while at(i + 1).is_ascii_digit() {
                    i += 1;
                }
                if c != '.' && at(i + 1) == '.' {
                    i += 1;
                }
                while at(i + 1).is_ascii_digit() {
                    i += 1;
                }
                let e = at(i + 1);
                let sign = matches!(at(i + 2), '+' | '-');
                if (e == 'e' || e == 'E') && at(i + 2 + usize::from(sign)).is_ascii_digit() {
                    i += 2 + usize::from(sign);
                    while at(i + 1).is_ascii_digit() {
                        i += 1;
                    }
                }
                let literal: String = chars[start..=i].iter().collect();
                match literal.parse::<f64>() {
                    Ok(v) if v.is_finite() => Tok::Number(v),
                    _ => return Err(err(format!("the number {literal} is out of range"))),
                }
            }
            _ if name_start(c) => {
                while name_part(at(i + 1)) {
                    i += 1;
                }
                Tok::Name(chars[start..=i].iter().collect())
            }
            _ => return Err(err(format!("unexpected character `{c}`"))),
        };
        i += 1;
        out.push(Token {
            tok,
            column: start + 1,
            text: chars[start..i].iter().collect(),
        });
    }
    out.push(Token {
        tok: Tok::End,
        column: chars.len() + 1,
        text: String::new(),
    });
    Ok(out)
}

/// A parsed piece: a condition (robustness) or a value (a comparison's side).
enum Value {
    Condition(Node),
    Number(Term),
}

struct Expr {
    value: Value,
    /// Where it starts.
    column: usize,
    /// Operators nested in it (≤ [`MAX_DEPTH`]).
    depth: usize,
}

/// A binary operator.
#[derive(Debug, Clone, Copy)]
enum Infix {
    Multiply,
    Add,
    Subtract,
    Compare(Comparison),
    Until,
    Since,
    Connective(Connective),
}

struct Parser {
    tokens: Vec<Token>,
    pos: usize,
    signals: Vec<String>,
    /// Current recursion depth of [`Parser::prefix`].
    nesting: usize,
}

impl Parser {
    fn peek(&self) -> &Token {
        // `lex` ends the tokens with `End`, and `advance` never passes it.
        &self.tokens[self.pos.min(self.tokens.len() - 1)]
    }

    fn advance(&mut self) -> Token {
        let t = self.peek().clone();
        if t.tok != Tok::End {
            self.pos += 1;
        }
        t
    }

    fn error_at(&self, t: &Token, expected: &str) -> StlError {
        let found = if t.tok == Tok::End {
            "the end".to_string()
        } else {
            format!("`{}`", t.text)
        };
        StlError::Parse {
            column: t.column,
            message: format!("expected {expected}, found {found}"),
        }
    }

    fn expect(&mut self, tok: Tok, what: &str) -> Result<(), StlError> {
        let t = self.advance();
        if t.tok == tok {
            Ok(())
        } else {
            Err(self.error_at(&t, what))
        }
    }

    /// The binary operator at the cursor and its level.
    fn infix(&self) -> Result<Option<(Infix, u8)>, StlError> {
        let t = self.peek();
        Ok(Some(match &t.tok {
            Tok::Star => (Infix::Multiply, MULTIPLY),
            Tok::Plus => (Infix::Add, ADD),
            Tok::Minus => (Infix::Subtract, ADD),
            Tok::Compare(c) => (Infix::Compare(*c), COMPARE),
            Tok::And => (Infix::Connective(Connective::And), AND),
            Tok::Or => (Infix::Connective(Connective::Or), OR),
            Tok::Implies => (Infix::Connective(Connective::Implies), IMPLIES),
            Tok::Iff => (Infix::Connective(Connective::Iff), IFF),
            Tok::Name(n) => match n.as_str() {
                "until" | "U" => (Infix::Until, UNTIL),
                "since" | "S" => (Infix::Since, SINCE),
                "and" => (Infix::Connective(Connective::And), AND),
                "or" => (Infix::Connective(Connective::Or), OR),
                "implies" => (Infix::Connective(Connective::Implies), IMPLIES),
                "iff" => (Infix::Connective(Connective::Iff), IFF),
                "xor" => (Infix::Connective(Connective::Xor), XOR),
                "unless" | "W" => return Err(unsupported(t)),
                _ => return Ok(None),
            },
            _ => return Ok(None),
        }))
    }

    /// An expression of operators binding at least as tight as `min`.
    fn expr(&mut self, min: u8) -> Result<Expr, StlError> {
        let mut lhs = self.prefix()?;
        while let Some((op, level)) = self.infix()? {
            if level < min {
                break;
            }
            let t = self.advance();
            let interval = match op {
                Infix::Until | Infix::Since => self.interval()?,
                _ => None,
            };
            let rhs = self.expr(level + 1)?;
            lhs = combine(&t, op, interval, lhs, rhs)?;
        }
        Ok(lhs)
    }

    /// A primary or a prefix operator with its operand.
    fn prefix(&mut self) -> Result<Expr, StlError> {
        self.nesting += 1;
        if self.nesting > 2 * MAX_DEPTH {
            let t = self.peek();
            return Err(StlError::Parse {
                column: t.column,
                message: format!("the formula is nested more than {MAX_DEPTH} deep"),
            });
        }
        let e = self.prefix_inner();
        self.nesting -= 1;
        e
    }

    fn prefix_inner(&mut self) -> Result<Expr, StlError> {
        let t = self.advance();
        let column = t.column;
        let leaf = |value| Expr {
            value,
            column,
            depth: 1,
        };
        match &t.tok {
            Tok::LParen => {
                let e = self.expr(0)?;
                self.expect(Tok::RParen, "`)` or an operator")?;
                Ok(Expr { column, ..e })
            }
            Tok::Minus => {
                let e = self.expr(NEGATE)?;
                let term = number(&t, e.value, "`-`")?;
                Ok(Expr {
                    value: Value::Number(match term {
                        Term::Number(c) => Term::Number(-c),
                        term => Term::Negate(Box::new(term)),
                    }),
                    column,
                    depth: deeper(&t, e.depth)?,
                })
            }
            Tok::Bang => self.prefix_operator(&t, None),
            Tok::Number(v) => Ok(leaf(Value::Number(Term::Number(*v)))),
            Tok::Quoted(name) => Ok(leaf(Value::Number(self.signal(name)))),
            Tok::Name(name) => match name.as_str() {
                "not" => self.prefix_operator(&t, None),
                "always" | "G" => self.temporal(&t, Prefix::Always),
                "eventually" | "F" => self.temporal(&t, Prefix::Eventually),
                "historically" | "H" => self.temporal(&t, Prefix::Historically),
                "once" | "O" => self.temporal(&t, Prefix::Once),
                "true" | "TRUE" => Ok(leaf(Value::Condition(Node::Constant(true)))),
                "false" | "FALSE" => Ok(leaf(Value::Condition(Node::Constant(false)))),
                "abs" => {
                    self.expect(Tok::LParen, "`(` after `abs`")?;
                    let e = self.expr(0)?;
                    self.expect(Tok::RParen, "`)` or an operator")?;
                    let term = number(&t, e.value, "`abs`")?;
                    Ok(Expr {
                        value: Value::Number(Term::Abs(Box::new(term))),
                        column,
                        depth: deeper(&t, e.depth)?,
                    })
                }
                n if UNSUPPORTED.contains(&n) => Err(unsupported(&t)),
                n if KEYWORDS.contains(&n) => Err(self.error_at(&t, "a condition or a value")),
                n => {
                    let name = n.to_string();
                    Ok(leaf(Value::Number(self.signal(&name))))
                }
            },
            _ => Err(self.error_at(&t, "a condition or a value")),
        }
    }

    /// `not`/`!` (interval `None`) or a temporal prefix operator and its operand.
    fn prefix_operator(&mut self, t: &Token, temporal: Option<(Prefix, Option<Interval>)>) -> Result<Expr, StlError> {
        let e = self.expr(PREFIX)?;
        let depth = deeper(t, e.depth)?;
        let operand = Box::new(condition(t, e)?);
        Ok(Expr {
            value: Value::Condition(match temporal {
                None => Node::Not(operand),
                Some((p, interval)) => Node::Temporal(p, interval, operand),
            }),
            column: t.column,
            depth,
        })
    }

    fn temporal(&mut self, t: &Token, p: Prefix) -> Result<Expr, StlError> {
        let interval = self.interval()?;
        self.prefix_operator(t, Some((p, interval)))
    }

    /// An optional interval `[a, b]` / `[a:b]` of non-negative bounds with optional units.
    fn interval(&mut self) -> Result<Option<Interval>, StlError> {
        if self.peek().tok != Tok::LBracket {
            return Ok(None);
        }
        let open = self.advance();
        let (start, start_unit) = self.bound()?;
        let t = self.advance();
        if !matches!(t.tok, Tok::Comma | Tok::Colon) {
            return Err(self.error_at(&t, "`,` or `:` between the bounds"));
        }
        let (end, end_unit) = self.bound()?;
        let close = self.advance();
        if close.tok != Tok::RBracket {
            return Err(self.error_at(&close, "`]`"));
        }
        // A bound without a unit takes the other's (RTAMT's rule), else seconds.
        let start = start / start_unit.or(end_unit).unwrap_or(1.0);
        let end = end / end_unit.or(start_unit).unwrap_or(1.0);
        if start > end {
            return Err(StlError::Parse {
                column: open.column,
                message: format!("the interval [{start}, {end}] s starts after it ends"),
            });
        }
        Ok(Some(Interval { start, end }))
    }

    /// A bound: a number and an optional unit (its divisor to seconds).
    fn bound(&mut self) -> Result<(f64, Option<f64>), StlError> {
        let t = self.advance();
        let Tok::Number(v) = t.tok else {
            return Err(self.error_at(&t, "a bound (a non-negative number of seconds)"));
        };
        let unit = match &self.peek().tok {
            Tok::Name(u) => match u.as_str() {
                "s" => Some(1.0),
                "ms" => Some(1e3),
                "us" => Some(1e6),
                "ns" => Some(1e9),
                _ => None,
            },
            _ => None,
        };
        if unit.is_some() {
            self.advance();
        }
        Ok((v, unit))
    }

    /// The term of a signal, registering its name.
    fn signal(&mut self, name: &str) -> Term {
        let k = match self.signals.iter().position(|s| s == name) {
            Some(k) => k,
            None => {
                self.signals.push(name.to_string());
                self.signals.len() - 1
            }
        };
        Term::Signal(k)
    }
}

fn unsupported(t: &Token) -> StlError {
    StlError::Parse {
        column: t.column,
        message: format!("RTAMT's `{}` is not supported here", t.text),
    }
}

/// One more level of nesting, refused past [`MAX_DEPTH`].
fn deeper(t: &Token, depth: usize) -> Result<usize, StlError> {
    if depth >= MAX_DEPTH {
        return Err(StlError::Parse {
            column: t.column,
            message: format!("the formula is nested more than {MAX_DEPTH} deep"),
        });
    }
    Ok(depth + 1)
}

/// The operand of `op` as a value.
fn number(t: &Token, v: Value, op: &str) -> Result<Term, StlError> {
    match v {
        Value::Number(term) => Ok(term),
        Value::Condition(_) => Err(StlError::Parse {
            column: t.column,
            message: format!("{op} needs a value (signals and numbers), found a condition"),
        }),
    }
}

/// The operand of the operator at `t` as a condition.
fn condition(t: &Token, e: Expr) -> Result<Node, StlError> {
    match e.value {
        Value::Condition(n) => Ok(n),
        Value::Number(_) => Err(StlError::Parse {
            column: e.column,
            message: format!(
                "`{}` (column {}) needs a condition here, found a value: compare it, e.g. `x > 0`",
                t.text, t.column
            ),
        }),
    }
}

fn combine(t: &Token, op: Infix, interval: Option<Interval>, l: Expr, r: Expr) -> Result<Expr, StlError> {
    let depth = deeper(t, l.depth.max(r.depth))?;
    let column = l.column;
    let op_name = format!("`{}`", t.text);
    let value = match op {
        Infix::Multiply | Infix::Add | Infix::Subtract => {
            let (a, b) = (
                Box::new(number(t, l.value, &op_name)?),
                Box::new(number(t, r.value, &op_name)?),
            );
            Value::Number(match op {
                Infix::Multiply => Term::Multiply(a, b),
                Infix::Add => Term::Add(a, b),
                _ => Term::Subtract(a, b),
            })
        }
        Infix::Compare(c) => {
            let (a, b) = (number(t, l.value, &op_name)?, number(t, r.value, &op_name)?);
            Value::Condition(Node::Compare(c, a, b))
        }
        Infix::Until => Value::Condition(Node::Until(
            interval,
            Box::new(condition(t, l)?),
            Box::new(condition(t, r)?),
        )),
        Infix::Since => Value::Condition(Node::Since(
            interval,
            Box::new(condition(t, l)?),
            Box::new(condition(t, r)?),
        )),
        Infix::Connective(c) => {
            Value::Condition(Node::Binary(c, Box::new(condition(t, l)?), Box::new(condition(t, r)?)))
        }
    };
    Ok(Expr { value, column, depth })
}

impl fmt::Display for Formula {
    /// The canonical text: keywords spelled out, intervals in seconds, the fewest parentheses
    /// (parsing it gives the same formula).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut s = String::new();
        write_node(&mut s, &self.root, &self.signals)?;
        f.write_str(&s)
    }
}

fn node_level(n: &Node) -> u8 {
    match n {
        Node::Constant(_) => PRIMARY,
        Node::Compare(..) => COMPARE,
        Node::Not(_) | Node::Temporal(..) => PREFIX,
        Node::Until(..) => UNTIL,
        Node::Since(..) => SINCE,
        Node::Binary(c, ..) => match c {
            Connective::And => AND,
            Connective::Or => OR,
            Connective::Implies => IMPLIES,
            Connective::Iff => IFF,
            Connective::Xor => XOR,
        },
    }
}

fn term_level(t: &Term) -> u8 {
    match t {
        Term::Signal(_) | Term::Abs(_) => PRIMARY,
        Term::Number(c) if *c >= 0.0 && c.is_sign_positive() => PRIMARY,
        Term::Number(_) | Term::Negate(_) => NEGATE,
        Term::Add(..) | Term::Subtract(..) => ADD,
        Term::Multiply(..) => MULTIPLY,
    }
}

fn interval_text(out: &mut String, i: &Option<Interval>) -> fmt::Result {
    match i {
        Some(i) => write!(out, "[{}, {}]", i.start, i.end),
        None => Ok(()),
    }
}

/// Writes `inner` in parentheses when `paren`.
fn group(out: &mut String, paren: bool, inner: impl FnOnce(&mut String) -> fmt::Result) -> fmt::Result {
    if paren {
        out.push('(');
    }
    inner(out)?;
    if paren {
        out.push(')');
    }
    Ok(())
}

/// The canonical text of a subformula.
pub(super) fn write_node(out: &mut String, n: &Node, names: &[String]) -> fmt::Result {
    let level = node_level(n);
    let binary = |out: &mut String, l: &Node, op: &str, i: &Option<Interval>, r: &Node| -> fmt::Result {
        group(out, node_level(l) < level, |o| write_node(o, l, names))?;
        write!(out, " {op}")?;
        interval_text(out, i)?;
        out.push(' ');
        group(out, node_level(r) <= level, |o| write_node(o, r, names))
    };
    match n {
        Node::Constant(b) => write!(out, "{b}"),
        Node::Compare(c, l, r) => {
            write_term(out, l, names)?;
            write!(out, " {} ", c.symbol())?;
            write_term(out, r, names)
        }
        Node::Not(c) => {
            out.push_str("not ");
            group(out, node_level(c) < PREFIX, |o| write_node(o, c, names))
        }
        Node::Temporal(p, i, c) => {
            out.push_str(match p {
                Prefix::Always => "always",
                Prefix::Eventually => "eventually",
                Prefix::Historically => "historically",
                Prefix::Once => "once",
            });
            interval_text(out, i)?;
            out.push(' ');
            group(out, node_level(c) < PREFIX, |o| write_node(o, c, names))
        }
        Node::Until(i, l, r) => binary(out, l, "until", i, r),
        Node::Since(i, l, r) => binary(out, l, "since", i, r),
        Node::Binary(c, l, r) => {
            let op = match c {
                Connective::And => "and",
                Connective::Or => "or",
                Connective::Implies => "implies",
                Connective::Iff => "iff",
                Connective::Xor => "xor",
            };
            binary(out, l, op, &None, r)
        }
    }
}

fn write_term(out: &mut String, t: &Term, names: &[String]) -> fmt::Result {
    let level = term_level(t);
    let binary = |out: &mut String, l: &Term, op: &str, r: &Term| -> fmt::Result {
        group(out, term_level(l) < level, |o| write_term(o, l, names))?;
        write!(out, " {op} ")?;
        group(out, term_level(r) <= level, |o| write_term(o, r, names))
    };
    match t {
        Term::Signal(k) => write_name(out, names.get(*k).map_or("", String::as_str)),
        Term::Number(c) => write!(out, "{c}"),
        Term::Negate(c) => {
            out.push('-');
            group(out, term_level(c) < NEGATE, |o| write_term(o, c, names))
        }
        Term::Abs(c) => {
            out.push_str("abs(");
            write_term(out, c, names)?;
            out.push(')');
            Ok(())
        }
        Term::Add(l, r) => binary(out, l, "+", r),
        Term::Subtract(l, r) => binary(out, l, "-", r),
        Term::Multiply(l, r) => binary(out, l, "*", r),
    }
}

/// A signal name, quoted when it is not a plain name or is a keyword.
fn write_name(out: &mut String, name: &str) -> fmt::Result {
    let mut chars = name.chars();
    let plain = chars.next().is_some_and(name_start)
        && chars.all(name_part)
        && !KEYWORDS.contains(&name)
        && !UNSUPPORTED.contains(&name);
    if plain {
        out.push_str(name);
    } else if name.contains('"') {
        write!(out, "`{name}`")?;
    } else {
        write!(out, "\"{name}\"")?;
    }
    Ok(())
}
