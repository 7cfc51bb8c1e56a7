%% @doc Internal. One evatar_web_thing per entry of the http option
%% `things' (docs/wot.md), child id `{thing, Pairing}'. A consumer that
%% crashes is restarted (it joins again); intensity is low so a defect does
%% not loop.
-module(evatar_web_things_sup).
-behaviour(supervisor).

-export([start_link/0, init/1, consumer/1, consumers/0]).

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

%% @private
-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Things = application:get_env(evatar_web, things, []),
    Children = [#{id => {thing, P},
                  start => {evatar_web_thing, start_link, [config(T)]}}
                || #{pairing := P} = T <- [normalise(T0) || T0 <- Things]],
    {ok, {#{strategy => one_for_one, intensity => 5, period => 10}, Children}}.

%% @doc The consumer of pairing `P', if configured and running.
-spec consumer(binary()) -> {ok, pid()} | error.
consumer(P) ->
    case [Pid || {{thing, Id}, Pid, _, _} <- children(), Id =:= P, is_pid(Pid)] of
        [Pid] -> {ok, Pid};
        [] -> error
    end.

%% @doc Every running consumer: `[{Pairing, Pid}]', sorted.
-spec consumers() -> [{binary(), pid()}].
consumers() ->
    lists:sort([{P, Pid} || {{thing, P}, Pid, _, _} <- children(), is_pid(Pid)]).

children() ->
    case whereis(?MODULE) of
        undefined -> [];
        _ -> supervisor:which_children(?MODULE)
    end.

normalise(#{pairing := P} = T) ->
    T#{pairing := bin(P), credential => bin(maps:get(credential, T)),
       entity_id => bin(maps:get(entity_id, T, <<"wot">>))}.

config(#{pairing := P, credential := C, entity_id := E}) ->
    #{pairing => P, credential => C, entity_id => E}.

bin(B) when is_binary(B) -> B;
bin(L) when is_list(L) -> unicode:characters_to_binary(L).
