//! The hidden `cell ipc-peer` (helper processes of tests and of `cell bench ipc`,
//! which is in `bench::ipc`).

use crate::ipc::peer::{self, PeerSpec};
use anyhow::Context;
use clap::Args;
use std::process::ExitCode;

/// Options of the hidden `cell ipc-peer`.
#[derive(Debug, Args)]
pub struct PeerArgs {
    /// What the peer does: a JSON `PeerSpec` (see `graspcell::ipc::peer`).
    pub spec: String,
}

/// Runs the hidden `cell ipc-peer '<json>'`.
pub fn run_peer(args: PeerArgs) -> anyhow::Result<ExitCode> {
    let spec: PeerSpec =
        serde_json::from_str(&args.spec).context("ipc-peer: parsing the peer spec")?;
    peer::run(&spec).context("ipc-peer")?;
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use clap::Parser;

    #[test]
    fn the_peer_subcommand_has_the_name_the_library_spawns() {
        let cli = Cli::try_parse_from(["cell", crate::ipc::peer::PEER_SUBCOMMAND, "{}"]).unwrap();
        assert!(matches!(cli.command, Command::IpcPeer(_)));
    }
}
