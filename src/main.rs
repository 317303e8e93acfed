//! The `bench` binary: everything lives in [`cli`].

mod cli;

/// The system allocator, counting the daemon's jobs that compute against
/// their memory budgets ([`bench::job_memory`]).
#[global_allocator]
static ALLOCATOR: bench::job_memory::BudgetAllocator = bench::job_memory::BudgetAllocator;

fn main() -> std::process::ExitCode {
    cli::main()
}
