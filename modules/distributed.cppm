// canopy.distributed — work shared across processes with MPI (Open MPI), results identical to one
// process. Replicated data, distributed work (the "offload" model of OSPRay's MPI module): every
// process (rank) loads and compiles the scene itself; rank 0 deals out work items on request, so
// that fast ranks take more, and gathers the results.
//
//   :session        launch detection (mpirun's environment) and MPI_Init_thread / MPI_Finalize;
//                   a program started without mpirun never touches MPI
//   :communicator   rank, size and the few collectives the rest needs
//   :agreement      error propagation: every rank learns the first failing rank's message
//   :dealer         the dynamic work dealer: item ranges handed out on request, results gathered
//                   on rank 0
//   :tiles          render_tiles across ranks (canopy.render's tiles, pixels gathered on rank 0)
//
// Built with CANOPY_WITH_MPI (target canopy_distributed). Only the main thread of each process
// calls MPI (MPI_THREAD_FUNNELED); oneTBB's workers never do.
export module canopy.distributed;
export import :session;
export import :communicator;
export import :agreement;
export import :dealer;
export import :tiles;
