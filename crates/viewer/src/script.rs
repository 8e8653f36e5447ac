//! Viewer actions and scripts of timed actions.
//!
//! Keyboard and mouse input are turned into the same [`Action`]s that a script file holds, so a
//! scripted session exercises exactly the code paths of an interactive one. A script is a text
//! file of lines `FRAME ACTION [ARGS…]` (`#` starts a comment); actions of frame f are applied
//! before frame f is rendered:
//!
//! ```text
//! # frame  action        arguments
//! 0        sun           30 45      # azimuth, elevation in degrees
//! 2        orbit         15 -5      # camera yaw, pitch in degrees
//! 3        pan           0.1 0      # right, up, in units of the camera distance
//! 4        zoom          0.8        # distance factor
//! 5        sun-move      10 0       # add to azimuth, elevation
//! 6        play-sun                 # toggle the sun's motion
//! 6        play-density             # toggle the density animation
//! 7        method        pt         # pm | pm-march | pt | rpnn | rpnn-dirs
//! 8        resize        640 400
//! 9        screenshot    out/a.png
//! 9        save-scene    out/a.toml
//! 10       quit
//! ```

use std::path::{Path, PathBuf};

/// How the viewer shows a [`nimbus_render::Method`]. The viewer shows `pm`, `pm-march`, `pt`
/// and `rpnn`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewMode {
    /// Photon mapping with final gathering: the ring follows every change (Elek 2012 §4.1),
    /// gathered samples accumulate while the view is still.
    Pm,
    /// Ray-marched photon mapping, live (Elek 2012): the ring follows every change, impostors
    /// (§4.4) stand in while the view changes little.
    PmMarch,
    /// Progressive path tracing: one sample per pixel per frame, restarted on any change.
    Pt,
    /// RPNN (Kallweit 2017), progressive; needs a trained model. A sky through the model's
    /// sky head where it has one.
    Rpnn,
    /// RPNN with the paper's sky: network queries in sampled sky directions.
    RpnnDirs,
}

impl ViewMode {
    pub fn name(self) -> &'static str {
        self.method().describe()
    }

    /// The estimator this mode shows.
    pub fn method(self) -> nimbus_render::Method {
        match self {
            ViewMode::Pm => nimbus_render::Method::Pm,
            ViewMode::PmMarch => nimbus_render::Method::PmMarch,
            // The GPU path tracer where it supports the scene (the viewer falls back to the
            // CPU one).
            ViewMode::Pt => nimbus_render::Method::PtGpu,
            ViewMode::Rpnn => nimbus_render::Method::Rpnn,
            ViewMode::RpnnDirs => nimbus_render::Method::RpnnDirs,
        }
    }

    /// The mode of a method name (`pm`, `pm-march`, `pt`, `rpnn`, `rpnn-dirs`); an error for
    /// the others.
    pub fn parse(s: &str) -> Result<Self, String> {
        let m: nimbus_render::Method = s.parse()?;
        match m {
            nimbus_render::Method::Pm => Ok(ViewMode::Pm),
            nimbus_render::Method::PmMarch => Ok(ViewMode::PmMarch),
            nimbus_render::Method::Pt => Ok(ViewMode::Pt),
            nimbus_render::Method::Rpnn => Ok(ViewMode::Rpnn),
            nimbus_render::Method::RpnnDirs => Ok(ViewMode::RpnnDirs),
            other => Err(format!(
                "the viewer shows pm, pm-march, pt, rpnn or rpnn-dirs, not `{other}`"
            )),
        }
    }
}

/// One user action.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Turn the camera about its target: yaw about +y, pitch up, in degrees.
    Orbit {
        yaw_deg: f64,
        pitch_deg: f64,
    },
    /// Move camera and target along the view's right and up axes, in units of the distance.
    Pan {
        right: f64,
        up: f64,
    },
    /// Multiply the camera's distance to its target.
    Zoom {
        factor: f64,
    },
    /// Set the sun's azimuth (about +y, from +z towards +x) and elevation, in degrees.
    SetSun {
        azimuth_deg: f64,
        elevation_deg: f64,
    },
    /// Add to the sun's azimuth and elevation, in degrees.
    MoveSun {
        azimuth_deg: f64,
        elevation_deg: f64,
    },
    ToggleSunMotion,
    ToggleDensityAnimation,
    Method(ViewMode),
    Resize {
        width: u32,
        height: u32,
    },
    Screenshot(PathBuf),
    SaveScene(PathBuf),
    Quit,
}

/// An action due before a given frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    pub frame: u32,
    pub action: Action,
}

/// A parse error naming the file and line.
#[derive(Debug, thiserror::Error)]
#[error("{file}:{line}: {msg}")]
pub struct ScriptError {
    pub file: String,
    pub line: usize,
    pub msg: String,
}

/// A script: timed actions sorted by frame (stable: same-frame actions keep their order).
#[derive(Debug, Clone, Default)]
pub struct Script {
    pub actions: Vec<Timed>,
}

impl Script {
    pub fn load(path: &Path) -> Result<Self, ScriptError> {
        // A pipe, a device, a folder or a bad link is refused at once (never waited on).
        let text = nimbus_scene::fsio::read_to_string(path).map_err(|e| ScriptError {
            file: path.display().to_string(),
            line: 0,
            msg: e.to_string(),
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    pub fn parse(text: &str, file: &str) -> Result<Self, ScriptError> {
        let mut actions = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let err = |msg: String| ScriptError {
                file: file.to_string(),
                line: i + 1,
                msg,
            };
            let words: Vec<&str> = line.split_whitespace().collect();
            let frame: u32 = words[0]
                .parse()
                .map_err(|_| err(format!("frame number expected, got `{}`", words[0])))?;
            let Some(&name) = words.get(1) else {
                return Err(err("an action is missing after the frame number".into()));
            };
            let args = &words[2..];
            let num = |k: usize| -> Result<f64, ScriptError> {
                let w = args
                    .get(k)
                    .ok_or_else(|| err(format!("`{name}` needs argument {}", k + 1)))?;
                let v: f64 = w
                    .parse()
                    .map_err(|_| err(format!("`{name}`: `{w}` is not a number")))?;
                if !v.is_finite() {
                    return Err(err(format!("`{name}`: `{w}` is not finite")));
                }
                Ok(v)
            };
            let count = |n: usize| -> Result<(), ScriptError> {
                if args.len() != n {
                    return Err(err(format!(
                        "`{name}` takes {n} argument(s), got {}",
                        args.len()
                    )));
                }
                Ok(())
            };
            let action = match name {
                "orbit" => {
                    count(2)?;
                    Action::Orbit {
                        yaw_deg: num(0)?,
                        pitch_deg: num(1)?,
                    }
                }
                "pan" => {
                    count(2)?;
                    Action::Pan {
                        right: num(0)?,
                        up: num(1)?,
                    }
                }
                "zoom" => {
                    count(1)?;
                    let f = num(0)?;
                    if f <= 0.0 {
                        return Err(err(format!("`zoom` factor must be positive, got {f}")));
                    }
                    Action::Zoom { factor: f }
                }
                "sun" => {
                    count(2)?;
                    Action::SetSun {
                        azimuth_deg: num(0)?,
                        elevation_deg: num(1)?,
                    }
                }
                "sun-move" => {
                    count(2)?;
                    Action::MoveSun {
                        azimuth_deg: num(0)?,
                        elevation_deg: num(1)?,
                    }
                }
                "play-sun" => {
                    count(0)?;
                    Action::ToggleSunMotion
                }
                "play-density" => {
                    count(0)?;
                    Action::ToggleDensityAnimation
                }
                "method" => {
                    count(1)?;
                    Action::Method(ViewMode::parse(args[0]).map_err(err)?)
                }
                "resize" => {
                    count(2)?;
                    let (w, h) = (num(0)?, num(1)?);
                    let ok = |v: f64| (1.0..=16384.0).contains(&v) && v.fract() == 0.0;
                    if !(ok(w) && ok(h)) {
                        return Err(err(format!(
                            "`resize` needs whole sizes in 1..=16384, got {w} {h}"
                        )));
                    }
                    Action::Resize {
                        width: w as u32,
                        height: h as u32,
                    }
                }
                "screenshot" | "save-scene" => {
                    count(1)?;
                    let p = PathBuf::from(args[0]);
                    if name == "screenshot" {
                        Action::Screenshot(p)
                    } else {
                        Action::SaveScene(p)
                    }
                }
                "quit" => {
                    count(0)?;
                    Action::Quit
                }
                other => return Err(err(format!("unknown action `{other}`"))),
            };
            actions.push(Timed { frame, action });
        }
        actions.sort_by_key(|t| t.frame);
        Ok(Self { actions })
    }

    /// The actions due before frame `frame`.
    pub fn due(&self, frame: u32) -> impl Iterator<Item = &Action> {
        self.actions
            .iter()
            .filter(move |t| t.frame == frame)
            .map(|t| &t.action)
    }

    /// The last frame any action is due at.
    pub fn last_frame(&self) -> Option<u32> {
        self.actions.last().map(|t| t.frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_action() {
        let s = Script::parse(
            "# test\n0 sun 30 45\n2 orbit 15 -5 # comment\n1 pan 0.1 0\n4 zoom 0.8\n5 sun-move 10 0\n\
             6 play-sun\n6 play-density\n7 method pt\n8 resize 640 400\n9 screenshot a.png\n\
             9 save-scene a.toml\n10 quit\n",
            "t",
        )
        .unwrap();
        assert_eq!(s.actions.len(), 12);
        assert_eq!(s.actions[1].frame, 1); // sorted by frame
        assert_eq!(
            s.due(0).next(),
            Some(&Action::SetSun {
                azimuth_deg: 30.0,
                elevation_deg: 45.0
            })
        );
        assert_eq!(s.due(6).count(), 2);
        assert_eq!(s.last_frame(), Some(10));
    }

    #[test]
    fn errors_name_file_and_line() {
        for (text, want) in [
            ("0 orbit 1\n", "t:1: `orbit` takes 2 argument(s), got 1"),
            ("\n\nx sun 1 2\n", "t:3: frame number expected, got `x`"),
            ("0 zoom -1\n", "t:1: `zoom` factor must be positive, got -1"),
            (
                "0 method foo\n",
                "t:1: unknown method `foo` (expected pt, pt-gpu, pm, pm-march, pm-elek2012, rpnn or rpnn-dirs)",
            ),
            (
                "0 method pt-gpu\n",
                "t:1: the viewer shows pm, pm-march, pt, rpnn or rpnn-dirs, not `pt-gpu`",
            ),
            ("0 fly\n", "t:1: unknown action `fly`"),
            ("0 sun NaN 3\n", "t:1: `sun`: `NaN` is not finite"),
            (
                "0 resize 0 10\n",
                "t:1: `resize` needs whole sizes in 1..=16384, got 0 10",
            ),
            ("3\n", "t:1: an action is missing after the frame number"),
        ] {
            assert_eq!(Script::parse(text, "t").unwrap_err().to_string(), want);
        }
    }
}
