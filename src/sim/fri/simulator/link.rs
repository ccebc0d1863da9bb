//! The link: which measurements were answered in time, the statistics over the
//! window, and the quality they give.

use super::{FriSimulator, STATS_WINDOW};
use crate::hw::fri::datagram::{LinkStats, Quality};
use crate::sim::fri::SimEvent;
use std::time::Duration;

impl FriSimulator {
    /// The link statistics over the last [`STATS_WINDOW`] measurements.
    pub fn link_stats(&self) -> LinkStats {
        let n = self.window.len();
        let latencies: Vec<f64> = self.window.iter().flatten().copied().collect();
        let answered = latencies.len();
        let (answer_rate, miss_rate) = if n == 0 {
            (0.0, 0.0)
        } else {
            let rate = answered as f64 / n as f64;
            (rate, 1.0 - rate)
        };
        let (mean, spread) = if latencies.is_empty() {
            (0.0, 0.0)
        } else {
            let max = latencies.iter().copied().fold(f64::MIN, f64::max);
            let min = latencies.iter().copied().fold(f64::MAX, f64::min);
            (latencies.iter().sum::<f64>() / answered as f64, max - min)
        };
        LinkStats {
            answer_rate: answer_rate as f32,
            latency_s: mean as f32,
            jitter_s: spread as f32,
            miss_rate: miss_rate as f32,
            miss_counter: self.counters.misses as u32,
        }
    }

    /// Books the latest measurement as answered in time or missed.
    pub(super) fn finish_cycle(&mut self) {
        if self.window.len() == STATS_WINDOW {
            self.window.pop_front();
        }
        self.window.push_back(self.current_latency_s);
        if self.current_latency_s.is_some() {
            self.consecutive_misses = 0;
            self.counters.answers_in_time += 1;
        } else {
            self.consecutive_misses += 1;
            self.counters.misses += 1;
        }
    }

    pub(super) fn update_quality(&mut self, now: Duration) {
        let t = self.config.quality;
        let n = self.window.len();
        let misses = self.window.iter().filter(|l| l.is_none()).count();
        let miss_rate = if n == 0 {
            1.0
        } else {
            misses as f64 / n as f64
        };
        let c = self.consecutive_misses;
        let quality = if n == 0
            || c >= t.unacceptable_consecutive_misses
            || miss_rate > t.bad_max_miss_rate
        {
            Quality::Unacceptable
        } else if c >= t.bad_consecutive_misses || miss_rate > t.ok_max_miss_rate {
            Quality::Bad
        } else if c >= 1 || miss_rate > t.perfect_max_miss_rate || n < STATS_WINDOW {
            Quality::Ok
        } else {
            Quality::Perfect
        };
        if quality != self.quality {
            let at_s = self.at_s(now);
            self.push_event(SimEvent::QualityChanged {
                from: self.quality,
                to: quality,
                at_s,
            });
            self.quality = quality;
        }
    }
}
